// `lftrack register`: one registration of two frames (files, or synthetic with --sim at a gold
// pose) against the scene's CT; prints the pose, per-view similarity, evaluations, time, TRE and the
// registration verdict (registration_verdict.hpp), and fails (exit 1) when the verdict rejects it.

#include <spdlog/spdlog.h>

#include <cmath>
#include <cstdio>
#include <optional>
#include <nlohmann/json.hpp>

#include "cli_commands.hpp"
#include "lftrack/loop/loop_summary.hpp"
#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/records/loop_json.hpp"
#include "lftrack/session/dicom_registration.hpp"
#include "lftrack/session/patient_setup.hpp"
#include "lftrack/session/registration_judge.hpp"
#include "lftrack/session/scene_exposure.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/session/scene_verdict.hpp"
#include "lftrack/sim_devices/sim_detectors.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"
#include "lftrack/tracking/frame_quality.hpp"
#include "lftrack/tracking/image_io.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::check_registration_path;
using session::check_views_observable;
using session::CtDicomIdentity;
using session::describe_exposure;
using session::DetectorSpec;
using session::locate_fiducial;
using session::LocatedFiducial;
using session::make_scene_renderer;
using session::nominal_delta_of;
using session::pose_from_nominal_delta;
using session::PreparedScene;
using session::RegistrationJudge;
using session::RegistrationSpec;
using session::room_frame_of_reference_uid;
using session::scene_ct_dicom_identity;
using session::scene_detector_corrections;
using session::scene_tre;
using session::scene_verdict_limits;
using session::SceneFrames;
using session::simulated_accuracy_caveat;
using session::SpatialRegistration;
using session::unobservable_direction_room;
using session::write_spatial_registration;
using sim_devices::make_scene_sim_detectors;

using loop::RegistrationVerdict;
using loop::verdict_text;
using loop::VerdictInput;
using loop::VerdictReason;

using records::pose_delta_json;
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
  std::string dicom_sro;  // the result as a DICOM Spatial Registration object
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

std::vector<std::string> view_names(const PreparedScene& p) {
  std::vector<std::string> names;
  for (const auto& d : p.scene.detectors) names.push_back(d.view.name);
  return names;
}

std::string pose_text(const std::vector<double>& d) {
  char s[160];
  std::snprintf(s, sizeof s, "t = (%.3f, %.3f, %.3f) mm, rotation vector (%.3f, %.3f, %.3f) deg", d[0], d[1], d[2], d[3],
                d[4], d[5]);
  return s;
}

nlohmann::json verdict_json(const RegistrationVerdict& v, const PreparedScene& p) {
  nlohmann::json j = {{"ok", v.ok}, {"reason", to_string(v.reason)}, {"text", verdict_text(v, view_names(p))}};
  j["view"] = v.view >= 0 && v.view < static_cast<int>(p.scene.detectors.size())
                  ? nlohmann::json(p.scene.detectors[static_cast<std::size_t>(v.view)].view.name)
                  : nlohmann::json(nullptr);
  j["value"] = std::isfinite(v.value) ? nlohmann::json(v.value) : nlohmann::json(nullptr);
  j["limit"] = std::isfinite(v.limit) ? nlohmann::json(v.limit) : nlohmann::json(nullptr);
  j["units"] = v.units;
  if (v.axis >= 0) j["axis"] = v.axis;
  if (v.reason == VerdictReason::kImageQuality) j["image_quality"] = tracking::to_string(v.quality_issue);
  return j;
}

// The verdict as the command's exit: OK when accepted.
Status verdict_status(const RegistrationVerdict& v, const PreparedScene& p) {
  if (v.ok) return {};
  return failed_precondition("registration " + verdict_text(v, view_names(p)));
}

// --dicom-sro: the result, if the verdict accepts it, as a DICOM Spatial Registration object (a
// rejected registration is not one of record: nothing is written, and the verdict's status says
// why). Reports on stderr with --json, which keeps stdout for the JSON.
Status write_dicom_result(const RegisterOptions& o, const PreparedScene& p, const std::optional<CtDicomIdentity>& ct,
                          const Pose& T_room_from_ct, const RegistrationVerdict& verdict, const std::string& method) {
  if (!ct) return {};
  FILE* to = o.json ? stderr : stdout;
  if (!verdict.ok) {
    std::fprintf(to, "  DICOM registration not written: the verdict rejected the result\n");
    return {};
  }
  SpatialRegistration reg;
  reg.T_room_from_ct = T_room_from_ct;
  reg.room_frame_of_reference_uid = room_frame_of_reference_uid(p.scene);
  reg.description = "lftrack register: " + method;
  LFTRACK_RETURN_IF_ERROR(write_spatial_registration(o.dicom_sro, *ct, reg));
  std::fprintf(to, "  wrote %s (DICOM Spatial Registration, CT series %s)\n", o.dicom_sro.c_str(),
               ct->series_uid.c_str());
  return {};
}

Status run(const RegisterOptions& o) {
  if (o.sim == !o.frames.empty()) return invalid_argument("give either --frames A B or --sim");
  if (!o.dicom_sro.empty()) LFTRACK_RETURN_IF_ERROR(check_registration_path(o.dicom_sro).with_context("--dicom-sro"));
  if (!o.save_frames.empty()) {  // a folder, or nothing yet: checked before the CT is loaded
    std::error_code ec;
    const auto status = std::filesystem::symlink_status(o.save_frames, ec);
    if (!ec && std::filesystem::exists(status) && !std::filesystem::is_directory(status))
      return failed_precondition("--save-frames " + o.save_frames + ": not a folder (the raw frames are written into one)");
  }
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  const PreparedScene& p = *prepared;
  std::optional<CtDicomIdentity> dicom_ct;  // read before any registration: a NIfTI CT is refused now
  if (!o.dicom_sro.empty()) {
    auto identity = scene_ct_dicom_identity(p.scene);
    if (!identity.ok()) return identity.status().with_context("--dicom-sro");
    dicom_ct = *identity;
  }
  LFTRACK_RETURN_IF_ERROR(check_views_observable(p.scene));
  const std::optional<Eigen::Vector3d> unobservable = unobservable_direction_room(p.scene);
  RegistrationSpec spec = p.scene.registration;
  if (!o.similarity.empty()) spec.similarity = o.similarity;
  std::string floors_from;
  auto limits = scene_verdict_limits(p, spec.similarity, &floors_from);
  if (!limits.ok()) return limits.status();
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

  // Each detector's correction as the loop takes it: the scene's detector calibration where it
  // names one; otherwise the simulator's detector model (its imager's, for --sim frames with
  // imaging physics), which a device detector's --frames may not use.
  auto corrections = scene_detector_corrections(p, o.sim);
  if (!corrections.ok()) return corrections.status();
  for (const DetectorSpec& d : p.scene.detectors)
    if (!d.calibration_file.empty())
      spdlog::info("detector {}: raw counts corrected with its calibration {}", d.view.name, d.calibration_file);
  const auto use_where_uncalibrated = [&](const tracking::DetectorCorrection& c) {
    for (std::size_t v = 0; v < corrections->size(); ++v)
      if (p.scene.detectors[v].calibration_file.empty()) (*corrections)[v] = c;
  };
  std::vector<Image<std::uint16_t>> raw;
  if (o.sim) {
    if (!gold) gold = p.nominal_T_room_from_ct;
    spdlog::info("simulated detectors, {}", describe_exposure(p));
    auto simulated = make_scene_sim_detectors(p, &pool);
    if (!simulated.ok()) return simulated.status();
    raw = simulated->detectors.make_frames();
    LFTRACK_RETURN_IF_ERROR(simulated->detectors.expose(*gold, o.seed * 7919, &raw));  // view i: seed * 7919 + i, as before
    if (simulated->correction) {
      use_where_uncalibrated(*simulated->correction);
      spdlog::info("synthetic frames with {} physics: {}", p.scene.sim.physics_name,
                   sim_spec::describe(p.scene.sim.physics));
    }
  } else {
    if (o.frames.size() != p.scene.detectors.size())
      return invalid_argument("--frames needs one file per detector (" + std::to_string(p.scene.detectors.size()) + ")");
    for (const auto& f : o.frames) {
      auto frame = read_frame(f);
      if (!frame.ok()) return frame.status();
      raw.push_back(std::move(frame).value());
    }
  }
  if (o.i0_counts > 0)
    for (tracking::DetectorCorrection& c : *corrections) c.open_field_counts = o.i0_counts;
  if (!o.save_frames.empty()) {
    std::error_code made;
    std::filesystem::create_directories(o.save_frames, made);
    if (made) return io_error("--save-frames " + o.save_frames + ": cannot create the folder: " + made.message());
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
  auto renderer = make_scene_renderer(p, o.renderer, o.lf_dir, &pool);
  if (!renderer.ok()) return renderer.status();
  auto judge = RegistrationJudge::create(p, *renderer, spec, *corrections, *limits, &pool);
  if (!judge.ok()) return judge.status();
  std::optional<LocatedFiducial> fiducial;
  const auto add_fiducial = [&](const SceneFrames& frames, tracking::Registration* registration) -> Status {
    auto located = locate_fiducial(p, frames, start, spec.gamma_per_mm);
    if (!located.ok()) return located.status();
    fiducial = *located;
    registration->set_fiducial(located->term);
    return {};
  };
  auto judged = (*judge)->judge(raw, start, *plan, o.fiducial ? RegistrationJudge::BeforeRun(add_fiducial) : nullptr);
  if (!judged.ok()) return judged.status();
  const VerdictInput& verdict_in = judged->input;
  const RegistrationVerdict& verdict = judged->verdict;
  if (!judged->registered) {  // a frame failed the image-quality gate: not registered, here as in the loop
    const std::vector<tracking::FrameQualityStats>& quality = judged->quality;
    if (o.json) {
      nlohmann::json j;
      j["scene"] = p.scene.source;
      j["similarity"] = spec.similarity;
      nlohmann::json views = nlohmann::json::array();
      for (std::size_t v = 0; v < raw.size(); ++v)
        views.push_back({{"name", p.scene.detectors[v].view.name},
                         {"image_quality", tracking::to_string(verdict_in.image_quality[v])},
                         {"saturated_fraction", quality[v].saturated_fraction},
                         {"dead_fraction", quality[v].dead_fraction},
                         {"mean_counts", quality[v].mean_counts},
                         {"relative_spread", quality[v].relative_spread}});
      j["views"] = views;
      j["verdict"] = verdict_json(verdict, p);
      std::printf("%s\n", j.dump(2).c_str());
    } else {
      std::printf("not registered %s: a frame failed the image-quality gate\n", p.scene.source.c_str());
      for (std::size_t v = 0; v < raw.size(); ++v)
        std::printf("  view %s: %s (saturated %.1f %%, dead %.1f %%, mean %.1f counts, spread %.3f)\n",
                    p.scene.detectors[v].view.name.c_str(), tracking::to_string(verdict_in.image_quality[v]),
                    100 * quality[v].saturated_fraction, 100 * quality[v].dead_fraction, quality[v].mean_counts,
                    quality[v].relative_spread);
      std::printf("  verdict: %s\n", verdict_text(verdict, view_names(p)).c_str());
    }
    return verdict_status(verdict, p);
  }
  const tracking::RegistrationResult* result = &judged->result;
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
    j["delta_from_nominal"] = pose_delta_json(verdict_in.delta_from_nominal.data());
    j["T_room_from_ct"] = {{"translation_mm", {t.x(), t.y(), t.z()}},
                           {"euler_deg", {{"roll", tracking::rad_to_deg(euler.roll)},
                                          {"pitch", tracking::rad_to_deg(euler.pitch)},
                                          {"yaw", tracking::rad_to_deg(euler.yaw)}}}};
    nlohmann::json views = nlohmann::json::array();
    for (std::size_t i = 0; i < result->view_similarity.size(); ++i) {
      nlohmann::json view = {{"name", p.scene.detectors[i].view.name},
                             {"similarity", result->view_similarity[i]},
                             {"image_quality", tracking::to_string(verdict_in.image_quality[i])}};
      if (verdict_in.has_check_ncc) view["check_ncc"] = verdict_in.check_ncc[i];
      if (verdict_in.has_view_shift) view["alone_moves_target_mm"] = verdict_in.view_shift_mm[i];
      views.push_back(view);
    }
    j["views"] = views;
    if (unobservable) j["unobservable_direction_room"] = {unobservable->x(), unobservable->y(), unobservable->z()};
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
    j["verdict"] = verdict_json(verdict, p);
    j["verdict"]["floors_from"] = floors_from;
    if (dicom_ct && verdict.ok) j["dicom_sro"] = o.dicom_sro;
    std::printf("%s\n", j.dump(2).c_str());
    LFTRACK_RETURN_IF_ERROR(write_dicom_result(o, p, dicom_ct, result->T_room_from_ct, verdict,
                                               plan->name + ", " + spec.similarity));
    return verdict_status(verdict, p);
  }
  std::printf("registered %s with %s (%s), %s renderer\n", p.scene.source.c_str(), plan->name.c_str(),
              spec.similarity.c_str(), o.renderer.c_str());
  std::printf("  delta from nominal: %s\n", pose_text(delta).c_str());
  std::printf("  T_room_from_ct: t = (%.3f, %.3f, %.3f) mm, Euler Rz*Ry*Rx roll %.3f pitch %.3f yaw %.3f deg\n",
              t.x(), t.y(), t.z(), tracking::rad_to_deg(euler.roll), tracking::rad_to_deg(euler.pitch),
              tracking::rad_to_deg(euler.yaw));
  for (std::size_t i = 0; i < result->view_similarity.size(); ++i) {
    std::printf("  view %s: %s = %.4f, check NCC = %.4f", p.scene.detectors[i].view.name.c_str(),
                spec.similarity.c_str(), result->view_similarity[i], verdict_in.check_ncc[i]);
    if (verdict_in.has_view_shift)
      std::printf(", registered alone it moves the target %.2f mm across it", verdict_in.view_shift_mm[i]);
    std::printf("\n");
  }
  if (verdict_in.has_view_shift) std::printf("  view check: %.1f ms\n", judged->view_check_ms);
  if (unobservable)
    std::printf("  single view: depth along (%.3f, %.3f, %.3f) (room frame) is unobservable\n", unobservable->x(),
                unobservable->y(), unobservable->z());
  if (fiducial)
    std::printf("  fiducial: distance %.3f mm at the result, triangulation gap %.3f mm\n",
                result->fiducial_distance_mm, fiducial->gap_mm);
  std::printf("  %d evaluations in %.1f ms (%s)\n", result->evaluations, result->elapsed_ms,
              tracking::to_string(result->stop));
  if (tre) {
    std::printf("  TRE: mean %.3f mm, max %.3f mm (initial mean %.3f mm) over %d points\n", tre->mean_mm, tre->max_mm,
                initial_tre->mean_mm, tre->points);
    if (const std::string caveat = simulated_accuracy_caveat(*p.ct); o.sim && !caveat.empty())
      std::printf("  note: %s\n", caveat.c_str());
  }
  std::printf("  verdict: %s\n", verdict_text(verdict, view_names(p)).c_str());
  std::printf("  verdict floors: %s\n", floors_from.c_str());
  LFTRACK_RETURN_IF_ERROR(
      write_dicom_result(o, p, dicom_ct, result->T_room_from_ct, verdict, plan->name + ", " + spec.similarity));
  return verdict_status(verdict, p);
}

}  // namespace

Command add_register_command(CLI::App* parent) {
  auto* app = parent->add_subcommand("register", "Register one pair of frames against the scene's CT");
  auto o = std::make_shared<RegisterOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--frames", o->frames, "Raw 16-bit frames, one per detector (TIFF or PNG)")->expected(1, 4);
  app->add_flag("--sim", o->sim,
                "Synthetic frames at --gold (exact ray casting, noise, blur, 12 bits; the scene's sim.physics)");
  const std::string pose_help = "tx,ty,tz (mm) and rx,ry,rz (rotation vector, deg) from the nominal pose";
  app->add_option("--gold", o->gold, "Gold pose: " + pose_help)->expected(6)->delimiter(',')->check(finite_in(-1e6, 1e6));
  app->add_option("--init", o->init, "Start pose: " + pose_help + " (default: nominal)")
      ->expected(6)
      ->delimiter(',')
      ->check(finite_in(-1e6, 1e6));
  const auto listed = [](const std::vector<std::string>& names) {
    std::string text;
    for (const auto& n : names) text += (text.empty() ? "" : ", ") + n;
    return text;
  };
  app->add_option("--plan", o->plan,
                  "Registration plan: " + listed(tracking::registration_plan_names()) + " (default: the scene's)");
  app->add_option("--similarity", o->similarity,
                  "Similarity: " + listed(tracking::similarity_names()) + " (default: the scene's)")
      ->check(CLI::IsMember(tracking::similarity_names()));
  app->add_option("--renderer", o->renderer, "DRR renderer")->capture_default_str();
  app->add_option("--lf-dir", o->lf_dir, "Light-field folder (default: out/lightfields/<scene>)");
  app->add_flag("--fiducial", o->fiducial, "Add the scene's first fiducial (hybrid measure, paper 2)");
  app->add_option("--seed", o->seed, "Noise seed of synthetic frames")->check(seed_value())->capture_default_str();
  app->add_option("--i0", o->i0_counts, "Open-field counts of every detector's frames (default: its calibration's, else the sim detector's)")
      ->check(finite_in(0, 1e9, true));
  app->add_option("--save-frames", o->save_frames, "Write the raw frames as 16-bit TIFF into this folder");
  app->add_flag("--json", o->json, "Print the result as JSON");
  app->add_option("--dicom-sro", o->dicom_sro,
                  "Write an accepted result as a DICOM Spatial Registration object referencing the planning CT "
                  "(the scene's CT must be a DICOM series); never over an existing file")
      ->check(not_empty());
  return [o] { return run(*o); };
}

}  // namespace lftrack::cli
