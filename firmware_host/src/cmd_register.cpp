// `lftrack register`: one registration of two frames (files, or synthetic with --sim at a gold
// pose) against the scene's CT; prints the pose, per-view similarity, evaluations, time and TRE.

#include <spdlog/spdlog.h>

#include <cstdio>
#include <nlohmann/json.hpp>

#include "cli_commands.hpp"
#include "lftrack/host/scene_registration.hpp"
#include "lftrack/tracking/image_io.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::host::cli {
namespace {

using tracking::Image;
using tracking::Pose;

struct RegisterOptions {
  SceneOptions scene;
  std::vector<std::string> frames;
  bool sim = false;
  std::vector<double> gold, init;
  std::string plan, similarity, renderer = "lightfield", lf_dir, save_frames;
  bool fiducial = false;
  std::uint64_t seed = 1;
  double i0_counts = 0;
  bool json = false;
};

Result<Image<std::uint16_t>> read_frame(const std::string& file) {
  const std::string ext = std::filesystem::path(file).extension().string();
  auto image = (ext == ".png") ? tracking::read_png(file) : tracking::read_tiff(file);
  if (!image.ok()) return image.status();
  Image<std::uint16_t> raw(image->rows(), image->cols());
  for (int r = 0; r < raw.rows(); ++r)
    for (int c = 0; c < raw.cols(); ++c) {
      const float v = image->at(r, c);
      if (!(v >= 0 && v <= 65535)) return invalid_argument(file + ": pixel values must be 16-bit counts");
      raw.at(r, c) = static_cast<std::uint16_t>(v + 0.5f);
    }
  return raw;
}

std::string pose_text(const std::vector<double>& d) {
  char s[160];
  std::snprintf(s, sizeof s, "t = (%.3f, %.3f, %.3f) mm, rotation vector (%.3f, %.3f, %.3f) deg", d[0], d[1], d[2], d[3],
                d[4], d[5]);
  return s;
}

Status run(const RegisterOptions& o) {
  if (o.sim == !o.frames.empty()) return invalid_argument("give either --frames A B or --sim");
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  const PreparedScene& p = *prepared;
  RegistrationSpec spec = p.scene.registration;
  if (!o.similarity.empty()) spec.similarity = o.similarity;
  if (!o.plan.empty()) spec.plan = o.plan;
  auto plan = tracking::registration_plan(spec.plan);
  if (!plan.ok()) return plan.status();

  std::optional<Pose> gold;
  if (!o.gold.empty()) {
    auto g = pose_from_nominal_delta(p, o.gold);
    if (!g.ok()) return g.status().with_context("--gold");
    gold = *g;
  }
  Pose start = p.nominal_T_room_from_ct;
  if (!o.init.empty()) {
    auto s = pose_from_nominal_delta(p, o.init);
    if (!s.ok()) return s.status().with_context("--init");
    start = *s;
  }

  std::vector<Image<std::uint16_t>> raw;
  tracking::DetectorCorrection correction = sim::detector_correction(scene_detector_model(p));
  if (o.i0_counts > 0) correction.open_field_counts = o.i0_counts;
  if (o.sim) {
    if (!gold) gold = p.nominal_T_room_from_ct;
    tracking::RendererOptions exact_options;
    exact_options.pool = &pool;
    auto exact = tracking::make_renderer("siddon", p.world_mu, exact_options);
    if (!exact.ok()) return exact.status();
    auto frames = synthesize_scene_frames(p, **exact, *gold, o.seed);
    if (!frames.ok()) return frames.status();
    raw = std::move(frames).value();
  } else {
    if (o.frames.size() != p.scene.detectors.size())
      return invalid_argument("--frames needs one file per detector (" + std::to_string(p.scene.detectors.size()) + ")");
    for (const auto& f : o.frames) {
      auto frame = read_frame(f);
      if (!frame.ok()) return frame.status();
      raw.push_back(std::move(frame).value());
    }
  }
  if (!o.save_frames.empty()) {
    std::filesystem::create_directories(o.save_frames);
    for (std::size_t i = 0; i < raw.size(); ++i) {
      Image<float> as_float(raw[i].rows(), raw[i].cols());
      for (std::size_t k = 0; k < raw[i].pixels().size(); ++k) as_float.pixels()[k] = raw[i].pixels()[k];
      tracking::ImageWriteOptions wo;
      wo.window = {0, 65535};
      const auto file = std::filesystem::path(o.save_frames) / ("frame_" + p.scene.detectors[i].view.name + ".tif");
      LFTRACK_RETURN_IF_ERROR(tracking::write_image(file, as_float.view(), wo));
      spdlog::info("wrote {}", file.string());
    }
  }
  auto frames = preprocess_scene_frames(p, raw, correction);
  if (!frames.ok()) return frames.status();

  auto renderer = make_scene_renderer(p, o.renderer, o.lf_dir, &pool);
  if (!renderer.ok()) return renderer.status();
  auto registration = make_scene_registration(p, *renderer, spec, &pool);
  if (!registration.ok()) return registration.status();
  LFTRACK_RETURN_IF_ERROR((*registration)->set_frames(frames->frames(), frames->masks()));
  std::optional<LocatedFiducial> fiducial;
  if (o.fiducial) {
    auto located = locate_fiducial(p, *frames, start, spec.gamma_per_mm);
    if (!located.ok()) return located.status();
    fiducial = *located;
    (*registration)->set_fiducial(located->term);
  }
  auto result = (*registration)->run(start, *plan);
  if (!result.ok()) return result.status();

  const std::vector<double> delta = nominal_delta_of(p, result->T_room_from_ct);
  const auto euler = tracking::euler_from_rotation(result->T_room_from_ct.linear());
  const Eigen::Vector3d t = result->T_room_from_ct.translation();
  std::optional<tracking::Tre> tre, initial_tre;
  if (gold) {
    tre = scene_tre(p, result->T_room_from_ct, *gold);
    initial_tre = scene_tre(p, start, *gold);
  }
  if (o.json) {
    nlohmann::json j;
    j["scene"] = p.scene.source;
    j["plan"] = plan->name;
    j["similarity"] = spec.similarity;
    j["renderer"] = o.renderer;
    j["delta_from_nominal"] = delta;
    j["T_room_from_ct"] = {{"translation_mm", {t.x(), t.y(), t.z()}},
                           {"euler_deg", {{"roll", tracking::rad_to_deg(euler.roll)},
                                          {"pitch", tracking::rad_to_deg(euler.pitch)},
                                          {"yaw", tracking::rad_to_deg(euler.yaw)}}}};
    nlohmann::json views = nlohmann::json::array();
    for (std::size_t i = 0; i < result->view_similarity.size(); ++i)
      views.push_back({{"name", p.scene.detectors[i].view.name}, {"similarity", result->view_similarity[i]}});
    j["views"] = views;
    j["evaluations"] = result->evaluations;
    j["ms"] = result->elapsed_ms;
    j["stop"] = tracking::to_string(result->stop);
    if (fiducial) {
      j["fiducial"] = {{"distance_mm", result->fiducial_distance_mm}, {"triangulation_gap_mm", fiducial->gap_mm}};
    }
    if (tre) {
      j["initial_tre_mm"] = {{"mean", initial_tre->mean_mm}, {"max", initial_tre->max_mm}};
      j["tre_mm"] = {{"mean", tre->mean_mm}, {"max", tre->max_mm}, {"points", tre->points}};
    }
    std::printf("%s\n", j.dump(2).c_str());
    return {};
  }
  std::printf("registered %s with %s (%s), %s renderer\n", p.scene.source.c_str(), plan->name.c_str(),
              spec.similarity.c_str(), o.renderer.c_str());
  std::printf("  delta from nominal: %s\n", pose_text(delta).c_str());
  std::printf("  T_room_from_ct: t = (%.3f, %.3f, %.3f) mm, Euler Rz*Ry*Rx roll %.3f pitch %.3f yaw %.3f deg\n",
              t.x(), t.y(), t.z(), tracking::rad_to_deg(euler.roll), tracking::rad_to_deg(euler.pitch),
              tracking::rad_to_deg(euler.yaw));
  for (std::size_t i = 0; i < result->view_similarity.size(); ++i)
    std::printf("  view %s: %s = %.4f\n", p.scene.detectors[i].view.name.c_str(), spec.similarity.c_str(),
                result->view_similarity[i]);
  if (fiducial)
    std::printf("  fiducial: distance %.3f mm at the result, triangulation gap %.3f mm\n",
                result->fiducial_distance_mm, fiducial->gap_mm);
  std::printf("  %d evaluations in %.1f ms (%s)\n", result->evaluations, result->elapsed_ms,
              tracking::to_string(result->stop));
  if (tre)
    std::printf("  TRE: mean %.3f mm, max %.3f mm (initial mean %.3f mm) over %d points\n", tre->mean_mm, tre->max_mm,
                initial_tre->mean_mm, tre->points);
  return {};
}

}  // namespace

Command add_register_command(CLI::App* parent) {
  auto* app = parent->add_subcommand("register", "Register one pair of frames against the scene's CT");
  auto o = std::make_shared<RegisterOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--frames", o->frames, "Raw 16-bit frames, one per detector (TIFF or PNG)")->expected(1, 4);
  app->add_flag("--sim", o->sim, "Synthetic frames at --gold (exact ray casting, noise, blur, 12 bits)");
  const std::string pose_help = "tx,ty,tz (mm) and rx,ry,rz (rotation vector, deg) from the nominal pose";
  app->add_option("--gold", o->gold, "Gold pose: " + pose_help)->expected(6)->delimiter(',');
  app->add_option("--init", o->init, "Start pose: " + pose_help + " (default: nominal)")->expected(6)->delimiter(',');
  app->add_option("--plan", o->plan, "Registration plan: papers, decoupled, cmaes, warm (default: the scene's)");
  app->add_option("--similarity", o->similarity, "Similarity: mi, nmi, ncc, gc, pi, gd (default: the scene's)");
  app->add_option("--renderer", o->renderer, "DRR renderer")->capture_default_str();
  app->add_option("--lf-dir", o->lf_dir, "Light-field folder (default: out/lightfields/<scene>)");
  app->add_flag("--fiducial", o->fiducial, "Add the scene's first fiducial (hybrid measure, paper 2)");
  app->add_option("--seed", o->seed, "Noise seed of synthetic frames")->capture_default_str();
  app->add_option("--i0", o->i0_counts, "Open-field counts of --frames (default: the sim detector's)");
  app->add_option("--save-frames", o->save_frames, "Write the raw frames as 16-bit TIFF into this folder");
  app->add_flag("--json", o->json, "Print the result as JSON");
  return [o] { return run(*o); };
}

}  // namespace lftrack::host::cli
