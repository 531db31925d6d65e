// `lftrack drr`: render DRRs of a scene at a pose and write them as images and float data.

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>

#include "cli_commands.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/image_io.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::default_light_field_dir;
using session::DetectorSpec;
using session::load_light_fields;
using session::load_scene;
using session::prepare_scene;
using session::PreparedScene;
namespace {

struct DrrOptions {
  SceneOptions scene;
  std::vector<std::string> views;  // empty: all
  std::vector<double> pose;        // tx ty tz [mm] rx ry rz [deg], rotation vector
  std::string renderer;            // empty: the scene's
  std::string out_dir = "out/drr";
  std::string image = "png";  // png | tif | none
  std::string data = "pfm";   // pfm | tif | none
  bool roi_only = false;
  int binning = 1;             // detector binning: K x K pixels become one
  std::vector<double> window;  // display window lo, hi (line integral)
  std::string lf_dir;          // light-field folder (default: default_light_field_dir)
};

Status run(const DrrOptions& o) {
  if (o.window.size() == 2 && !(o.window[0] < o.window[1]))
    return invalid_argument("--window low,high needs low below high");
  auto scene = load_scene(o.scene.scene);
  if (!scene.ok()) return scene.status();
  // Names are checked before the (slow) CT load.
  for (const auto& name : o.views) {
    const bool known = std::any_of(scene->detectors.begin(), scene->detectors.end(),
                                   [&](const DetectorSpec& d) { return d.view.name == name; });
    if (!known) return not_found("the scene has no view '" + name + "'");
  }
  const auto names = tracking::renderer_names();
  if (!o.renderer.empty() && std::find(names.begin(), names.end(), o.renderer) == names.end()) {
    return not_found("unknown renderer '" + o.renderer + "'");
  }
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = prepare_scene(*scene, o.scene.ct, &pool);
  if (!prepared.ok()) return prepared.status();
  const PreparedScene& p = *prepared;

  tracking::PoseDelta delta;
  if (!o.pose.empty()) {
    delta.translation_mm = {o.pose[0], o.pose[1], o.pose[2]};
    delta.rotation_rad = {tracking::deg_to_rad(o.pose[3]), tracking::deg_to_rad(o.pose[4]),
                          tracking::deg_to_rad(o.pose[5])};
  }
  const tracking::Pose T_room_from_ct =
      apply_delta(p.nominal_T_room_from_ct, delta, p.registration_origin_room_mm());

  tracking::RendererOptions ropts;
  ropts.pool = &pool;
  ropts.octree_pivot = p.scene.octree_pivot;
  const std::string renderer_name = o.renderer.empty() ? p.scene.renderer : o.renderer;
  if (renderer_name == "lightfield") {
    auto fields = load_light_fields(
        p, o.lf_dir.empty() ? default_light_field_dir(p.scene) : std::filesystem::path(o.lf_dir));
    if (!fields.ok()) return fields.status();
    ropts.light_fields = *fields;
  }
  auto renderer = tracking::make_renderer(renderer_name, p.mu, ropts);
  if (!renderer.ok()) return renderer.status();

  std::vector<int> selected;
  if (o.views.empty()) {
    for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) selected.push_back(int(i));
  } else {
    for (const auto& name : o.views) {
      const int i = p.detector_index(name);
      if (i < 0) return not_found("the scene has no view '" + name + "'");
      selected.push_back(i);
    }
  }
  std::error_code ec;
  std::filesystem::create_directories(o.out_dir, ec);
  if (ec) return io_error(o.out_dir + ": cannot create folder: " + ec.message());

  for (int i : selected) {
    const auto& detector = p.scene.detectors[std::size_t(i)].view;
    const tracking::PixelWindow area = o.roi_only ? p.roi_windows[std::size_t(i)]
                                                  : tracking::PixelWindow::full(detector.rows, detector.cols);
    // The rendered view: the chosen area of the detector, binned.
    const tracking::XrayView view =
        detector.resampled(area.row0, area.col0, area.rows, area.cols, std::max(1, area.rows / o.binning),
                           std::max(1, area.cols / o.binning));
    const tracking::PixelWindow window = tracking::PixelWindow::full(view.rows, view.cols);
    tracking::Image<float> drr(window.rows, window.cols);
    const auto t0 = std::chrono::steady_clock::now();
    tracking::RenderExtras extras;
    LFTRACK_RETURN_IF_ERROR((*renderer)->render(T_room_from_ct, view, window, drr.view(), &extras));
    if (extras.pose_outside_envelope)
      spdlog::warn("view {}: the pose is outside the scene's envelope", view.name);
    if (extras.masked_pixels > 0) {
      spdlog::warn("view {}: {} pixels outside the light field are masked (set to 0)", view.name,
                   extras.masked_pixels);
    }
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    spdlog::info("view {}: {} x {} {} DRR in {:.1f} ms", view.name, window.rows, window.cols, renderer_name,
                 ms);

    tracking::ImageWriteOptions wo;
    wo.window = o.window.size() == 2 ? tracking::DisplayWindow{o.window[0], o.window[1]}
                                     : tracking::percentile_window(drr.view(), 0.5, 99.8);
    const std::string stem = (std::filesystem::path(o.out_dir) / ("drr_" + view.name)).string();
    if (o.image != "none") {
      const std::string file = stem + (o.image == "tif" ? ".tif" : ".png");
      LFTRACK_RETURN_IF_ERROR(tracking::write_image(file, drr.view(), wo));
      std::printf("%s\n", file.c_str());
    }
    if (o.data != "none") {
      wo.float_data = true;
      const std::string file = stem + (o.data == "tif" ? "_mu_mm.tif" : "_mu_mm.pfm");
      LFTRACK_RETURN_IF_ERROR(tracking::write_image(file, drr.view(), wo));
      std::printf("%s\n", file.c_str());
    }
  }
  return {};
}

}  // namespace

Command add_drr_command(CLI::App* parent) {
  auto* app = parent->add_subcommand("drr", "Render DRRs of a scene's views at a pose");
  auto o = std::make_shared<DrrOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--view", o->views, "View(s) to render (default: all)");
  app->add_option("--pose", o->pose,
                  "Pose change about the registration origin: tx,ty,tz (mm, room) and rx,ry,rz "
                  "(rotation vector, degrees); default 0,0,0,0,0,0")
      ->expected(6)
      ->delimiter(',')
      ->check(finite_in(-1e6, 1e6));
  app->add_option("--renderer", o->renderer,
                  "Renderer (siddon, trilinear, lightfield; default: the scene's)");
  app->add_option("--lf-dir", o->lf_dir, "Light-field folder (default: out/lightfields/<scene>)");
  app->add_option("-o,--out", o->out_dir, "Output folder")->capture_default_str();
  app->add_option("--image", o->image, "Windowed 16-bit image: png, tif or none")
      ->check(CLI::IsMember({"png", "tif", "none"}))
      ->capture_default_str();
  app->add_option("--data", o->data, "Float line integrals (mu * mm): pfm, tif or none")
      ->check(CLI::IsMember({"pfm", "tif", "none"}))
      ->capture_default_str();
  app->add_flag("--roi", o->roi_only, "Render only each view's ROI window");
  app->add_option("--bin", o->binning, "Detector binning: K x K pixels become one")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  app->add_option("--window", o->window, "Display window low,high in mu*mm (default: 0.5-99.8 percentiles)")
      ->expected(2)
      ->delimiter(',')
      ->check(finite_in(-1e6, 1e6));
  return [o] { return run(*o); };
}

}  // namespace lftrack::cli
