// `lftrack calibrate views`: X-ray view geometry from one phantom image per detector (issue 8).
// `lftrack calibrate couch` lives in cmd_calibrate_couch.cpp.

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "cli_commands.hpp"
#include "lftrack/calib/two_view_calibration.hpp"
#include "lftrack/session/calibration_files.hpp"
#include "lftrack/sim/phantom_images.hpp"
#include "lftrack/tracking/image_io.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/random_draws.hpp"

namespace lftrack::cli {

using session::calibrated_detectors_yaml;
using session::load_calibration_phantom;
using session::load_scene;
namespace {

using tracking::Image;
using tracking::XrayView;

struct ViewsOptions {
  std::string phantom = "builtin";
  std::vector<std::string> images;
  std::string scene = "builtin:phantom";  // nominal geometry (and, with --sim, the truth)
  std::string out;
  bool counts = false;  // images are detector counts, not line integrals
  bool fit_pitch = false;
  bool sim = false;
  std::uint64_t seed = 1;
  double photons = 1e7;  // 100 averaged frames of 10^5 quanta
  std::string save_images;
  bool json = false;
};

// Line integrals from an image file; detector counts are converted with the open field taken
// as the 99.5th percentile of the image (the phantom covers less than half of it).
Result<Image<float>> read_line_integrals(const std::string& file, bool counts) {
  const std::string ext = std::filesystem::path(file).extension().string();
  auto image =
      ext == ".pfm"                       ? tracking::read_pfm(file)
      : (ext == ".tif" || ext == ".tiff") ? tracking::read_tiff(file)
      : ext == ".png"
          ? tracking::read_png(file)
          : Result<Image<float>>(invalid_argument(file + ": unknown image type (use .pfm, .tif or .png)"));
  if (!image.ok()) return image.status();
  if (!counts) return image;
  std::vector<float> values;
  for (int r = 0; r < image->rows(); ++r)
    for (int c = 0; c < image->cols(); ++c)
      if (std::isfinite(image->at(r, c))) values.push_back(image->at(r, c));
  if (values.empty()) return invalid_argument(file + ": no finite pixels");
  const std::size_t k = std::min(values.size() - 1, std::size_t(0.995 * double(values.size())));
  std::nth_element(values.begin(), values.begin() + std::ptrdiff_t(k), values.end());
  const double open = values[k];
  if (!(open > 0)) return invalid_argument(file + ": the open field (99.5th percentile) is not positive");
  for (int r = 0; r < image->rows(); ++r)
    for (int c = 0; c < image->cols(); ++c)
      image->at(r, c) = float(std::log(open / std::max(double(image->at(r, c)), 1e-3)));
  return image;
}

double orientation_error_deg(const XrayView& a, const XrayView& b) {
  return tracking::rad_to_deg(
      tracking::rotation_log(a.detector_axes().transpose() * b.detector_axes()).norm());
}

Eigen::Isometry3d random_placement(std::mt19937_64& rng, double mm, double deg) {
  std::uniform_real_distribution<double> u(-1, 1);
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = tracking::rotation_exp(tracking::draw3(u, rng) * tracking::deg_to_rad(deg));
  t.translation() = tracking::draw3(u, rng) * mm;
  return t;
}

// The drawings' view: the true one with its source, detector centre and tilt off by up to
// 5 mm, 3 mm and 1 degree.
XrayView nominal_from_truth(const XrayView& truth, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  XrayView v = truth;
  const Eigen::Vector3d centre = v.detector_centre_mm();
  const Eigen::Matrix3d tilt =
      tracking::rotation_exp(tracking::draw3(u, rng) * tracking::deg_to_rad(1.0));
  v.col_axis = tilt * v.col_axis;
  v.row_axis = tilt * v.row_axis;
  v.set_detector_centre(centre + 3 * tracking::draw3(u, rng));
  v.source_mm += 5 * tracking::draw3(u, rng);
  return v;
}

Status run(const ViewsOptions& o) {
  auto phantom = load_calibration_phantom(o.phantom);
  if (!phantom.ok()) return phantom.status();
  auto scene = load_scene(o.scene);
  if (!scene.ok()) return scene.status();
  if (scene->detectors.size() != 2) {
    return invalid_argument("calibrate views needs a scene with two detectors; '" + o.scene + "' has " +
                            std::to_string(scene->detectors.size()));
  }
  const std::array<XrayView, 2> scene_views = {scene->detectors[0].view, scene->detectors[1].view};
  std::array<XrayView, 2> nominal = scene_views;
  std::array<Image<float>, 2> images;
  Eigen::Isometry3d T_room_from_phantom = Eigen::Isometry3d::Identity();
  if (o.sim) {
    // The scene's views are the truth; the phantom is placed a few mm and degrees off, and the
    // nominal views differ from the truth as drawings do.
    std::mt19937_64 rng(o.seed);
    T_room_from_phantom = random_placement(rng, 3.0, 2.0);
    for (std::size_t k = 0; k < 2; ++k) {
      nominal[k] = nominal_from_truth(scene_views[k], rng);
      sim::PhantomImageSpec spec;
      spec.photons_per_pixel = o.photons;
      spec.seed = o.seed * 1000 + k;
      spdlog::info("rendering the phantom in view {} ({} x {} pixels)", scene_views[k].name,
                   scene_views[k].rows, scene_views[k].cols);
      auto image = sim::render_phantom_image(*phantom, T_room_from_phantom, scene_views[k], spec);
      if (!image.ok()) return image.status();
      images[k] = std::move(*image);
      if (!o.save_images.empty()) {
        std::filesystem::create_directories(o.save_images);
        const auto file = std::filesystem::path(o.save_images) / ("phantom_" + scene_views[k].name + ".pfm");
        LFTRACK_RETURN_IF_ERROR(tracking::write_image(file, images[k].view(), {}));
        spdlog::info("wrote {}", file.string());
      }
    }
  } else {
    if (o.images.size() != 2) return invalid_argument("--images needs two files, one per detector (A B)");
    for (std::size_t k = 0; k < 2; ++k) {
      auto image = read_line_integrals(o.images[k], o.counts);
      if (!image.ok()) return image.status();
      images[k] = std::move(*image);
    }
  }
  calib::ViewCalibrationOptions options;
  options.fit_pitch = o.fit_pitch;
  auto cal = calib::calibrate_two_views(*phantom, {images[0].view(), images[1].view()}, nominal,
                                        Eigen::Isometry3d::Identity(), options);
  if (!cal.ok()) return cal.status();
  for (std::size_t k = 0; k < 2; ++k) {
    const calib::ViewCalibration& c = cal->in_phantom[k];
    spdlog::info(
        "view {}: {} of {} markers matched ({} blobs found, {} merged), rms {:.3f} px, source sd {:.3f} mm",
        c.view.name, c.markers_matched, c.markers_projected, c.detections, cal->scans[k].rejected_merged,
        c.rms_px, c.source_sd_mm.norm());
  }
  if (!o.out.empty()) {
    std::ofstream out(o.out);
    const std::string provenance = o.sim ? "simulated (seed " + std::to_string(o.seed) + ")"
                                         : "images " + o.images[0] + " " + o.images[1];
    out << calibrated_detectors_yaml(scene->detectors, *cal,
                                     "phantom '" + phantom->name + "', " + provenance);
    if (!out) return io_error("cannot write '" + o.out + "'");
    spdlog::info("wrote {}", o.out);
  }
  nlohmann::json j;
  j["phantom"] = phantom->name;
  j["central_ray_gap_mm"] = cal->room.central_ray_gap_mm;
  double source_error = 0, detector_error = 0, orientation_error = 0, rms = 0;
  for (std::size_t k = 0; k < 2; ++k) {
    const calib::ViewCalibration& c = cal->in_phantom[k];
    nlohmann::json v;
    v["name"] = c.view.name;
    v["rms_px"] = c.rms_px;
    v["markers_matched"] = c.markers_matched;
    v["source_sd_mm"] = c.source_sd_mm.norm();
    v["pixel00_sd_mm"] = c.pixel00_sd_mm.norm();
    v["orientation_sd_deg"] = c.orientation_sd_deg.norm();
    v["source_mm"] = {cal->views_room[k].source_mm.x(), cal->views_room[k].source_mm.y(),
                      cal->views_room[k].source_mm.z()};
    rms = std::max(rms, c.rms_px);
    if (o.sim) {
      const XrayView& got = cal->views_room[k];
      const XrayView& want = scene_views[k];
      v["source_error_mm"] = (got.source_mm - want.source_mm).norm();
      v["detector_error_mm"] = (got.pixel00_mm - want.pixel00_mm).norm();
      v["orientation_error_deg"] = orientation_error_deg(got, want);
      source_error = std::max(source_error, (got.source_mm - want.source_mm).norm());
      detector_error = std::max(detector_error, (got.pixel00_mm - want.pixel00_mm).norm());
      orientation_error = std::max(orientation_error, orientation_error_deg(got, want));
    }
    j["views"].push_back(v);
  }
  j["rms_px"] = rms;
  if (o.sim) {
    j["seed"] = o.seed;
    j["photons_per_pixel"] = o.photons;
    j["source_error_mm"] = source_error;  // the worse of the two views
    j["detector_error_mm"] = detector_error;
    j["orientation_error_deg"] = orientation_error;
  }
  if (o.json) {
    std::printf("%s\n", j.dump(2).c_str());
  } else if (o.sim) {
    std::printf(
        "recovered the simulated room: source error %.3f mm, detector error %.3f mm, orientation error "
        "%.4f deg, rms %.3f px (worse of the two views)\n",
        source_error, detector_error, orientation_error, rms);
  }
  return {};
}

}  // namespace

Command add_calibrate_views_command(CLI::App* parent) {
  auto o = std::make_shared<ViewsOptions>();
  CLI::App* app = parent->add_subcommand(
      "views", "X-ray view geometry from one image of a calibration phantom per detector");
  app->add_option("--phantom", o->phantom, "Phantom file (YAML), or 'builtin'")->capture_default_str();
  app->add_option("--images", o->images,
                  "One phantom image per detector, in the scene's order (.pfm, .tif, .png)")
      ->expected(2);
  app->add_option("--scene", o->scene,
                  "Scene whose detectors are the nominal geometry (with --sim: the truth)")
      ->capture_default_str();
  app->add_option("--out", o->out, "Write the calibrated detectors section (YAML) here");
  app->add_flag("--counts", o->counts, "Images are detector counts (the default: line integrals, ln(I0/I))");
  app->add_flag("--fit-pitch", o->fit_pitch,
                "Solve the pixel pitch, holding the source-to-detector distance at the nominal value");
  app->add_flag("--sim", o->sim,
                "Render the phantom at the scene's geometry, calibrate, print recovery errors");
  app->add_option("--seed", o->seed, "With --sim: placement, drawing errors and noise")->check(seed_value())
      ->capture_default_str();
  app->add_option("--photons", o->photons, "With --sim: open-field quanta per pixel, 0 (no noise) to 1e9")
      ->check(finite_in(0, 1e9))
      ->capture_default_str();
  app->add_option("--save-images", o->save_images,
                  "With --sim: write the phantom images (.pfm) to this folder");
  app->add_flag("--json", o->json, "Print the report as JSON on stdout");
  return [o] {
    if (o->sim && !o->images.empty()) return invalid_argument("give either --sim or --images, not both");
    if (!o->sim && o->images.empty()) return invalid_argument("give --images A B (or --sim)");
    return run(*o);
  };
}

}  // namespace lftrack::cli
