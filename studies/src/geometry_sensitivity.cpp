#include "lftrack/studies/geometry_sensitivity.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"

#include <spdlog/spdlog.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <random>
#include <sstream>

#include "lftrack/session/progress_bar.hpp"
#include "lftrack/session/registration_judge.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/session/scene_verdict.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::studies {

using session::DetectorSpec;
using session::make_scene_registration;
using session::pose_at_tre;
using session::PreparedScene;
using session::preprocess_scene_frames;
using session::ProgressBar;
using session::scene_tre;
using session::scene_verdict_limits;
using session::verdict_input_of;
using sim_devices::scene_detector_model;
using sim_devices::synthesize_scene_frames;

using loop::judge_registration;
using loop::RegistrationVerdict;

using tracking::Pose;
using tracking::XrayView;

namespace {

struct Perturbation {
  std::string key, name;
  std::function<void(std::vector<DetectorSpec>&)> apply;
};

Eigen::Vector3d beam_of(const XrayView& v) {
  return (v.principal_point_mm() - v.source_mm).normalized();
}

// Rotates the detector by `angle_rad` about `axis` through its centre.
void tilt_detector(XrayView& v, const Eigen::Vector3d& axis, double angle_rad) {
  const Eigen::Vector3d centre = v.detector_centre_mm();
  const Eigen::Matrix3d r = tracking::rotation_exp(axis.normalized() * angle_rad);
  v.col_axis = r * v.col_axis;
  v.row_axis = r * v.row_axis;
  v.set_detector_centre(centre);
}

void scale_pitch(XrayView& v, double factor) {
  const Eigen::Vector3d centre = v.detector_centre_mm();
  v.pitch_col_mm *= factor;
  v.pitch_row_mm *= factor;
  v.set_detector_centre(centre);
}

std::vector<Perturbation> perturbations() {
  const double tenth_deg = tracking::deg_to_rad(0.1);
  return {
      {"no-error", "no error", [](std::vector<DetectorSpec>&) {}},
      {"source-along", "source of view 1 moved 1 mm along its beam",
       [](std::vector<DetectorSpec>& d) { d[0].view.source_mm += beam_of(d[0].view); }},
      {"source-across", "source of view 1 moved 1 mm across its beam (along the detector columns)",
       [](std::vector<DetectorSpec>& d) { d[0].view.source_mm += d[0].view.col_axis; }},
      {"detector-tilt", "detector of view 1 tilted 0.1 deg about its row axis",
       [=](std::vector<DetectorSpec>& d) { tilt_detector(d[0].view, d[0].view.row_axis, tenth_deg); }},
      {"detector-rotation", "detector of view 1 rotated 0.1 deg in its plane",
       [=](std::vector<DetectorSpec>& d) { tilt_detector(d[0].view, beam_of(d[0].view), tenth_deg); }},
      {"detector-shift", "detector of view 1 moved 0.1 mm in its plane (along the columns)",
       [](std::vector<DetectorSpec>& d) { d[0].view.pixel00_mm += 0.1 * d[0].view.col_axis; }},
      {"pitch", "pitch of both detectors off by +0.1%",
       [](std::vector<DetectorSpec>& d) {
         for (auto& s : d) scale_pitch(s.view, 1.001);
       }},
  };
}

}  // namespace

Result<SensitivityReport> run_geometry_sensitivity(const PreparedScene& truth, const SensitivityOptions& o,
                                                   tracking::ThreadPool* pool) {
  if (o.runs < 1) return invalid_argument("sensitivity: runs must be at least 1");
  if (truth.scene.detectors.empty()) return invalid_argument("sensitivity: the scene has no detector");
  auto plan = tracking::registration_plan(o.plan);
  if (!plan.ok()) return plan.status();
  tracking::RendererOptions ray_options;
  ray_options.pool = pool;
  auto exact = tracking::make_renderer("siddon", truth.world_mu, ray_options);
  if (!exact.ok()) return exact.status();
  // Inside the registration, single-threaded: the registration runs its views on the pool.
  auto made = tracking::make_renderer("siddon", truth.mu, {});
  if (!made.ok()) return made.status();
  const std::shared_ptr<const tracking::DrrRenderer> inside = std::move(*made);
  const tracking::DetectorCorrection correction = sim::detector_correction(scene_detector_model(truth));
  const Eigen::Vector3d origin = truth.registration_origin_room_mm();
  // The scene's verdict for its measure, resolved once from the true scene (a commissioning file
  // describes the scene's geometry, not a perturbed model of it).
  auto limits = scene_verdict_limits(truth, truth.scene.registration.similarity);
  if (!limits.ok()) return limits.status();

  // Gold poses, starts and raw frames, shared by every case.
  struct Problem {
    Pose gold, start;
    std::vector<tracking::Image<std::uint16_t>> raw;
  };
  std::vector<Problem> problems;
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int i = 0; i < o.runs; ++i) {
    tracking::Vector6d d, dir;
    for (int k = 0; k < 6; ++k) {
      d(k) = k < 3 ? 3 * u(rng) : tracking::deg_to_rad(2 * u(rng));
      dir(k) = k < 3 ? u(rng) : tracking::deg_to_rad(u(rng));
    }
    Problem p;
    p.gold = tracking::apply_delta(truth.nominal_T_room_from_ct, tracking::PoseDelta::from_vector(d), origin);
    p.start = pose_at_tre(truth, p.gold, dir, o.start_tre_mm);
    auto raw = synthesize_scene_frames(truth, **exact, p.gold, o.seed * 1000 + std::uint64_t(i));
    if (!raw.ok()) return raw.status();
    p.raw = std::move(*raw);
    problems.push_back(std::move(p));
  }

  SensitivityReport report;
  report.scene = truth.scene.source;
  report.plan = o.plan;
  report.runs = o.runs;
  report.measure = truth.scene.registration.similarity;
  report.verdict_tolerance_mm = truth.scene.safety.beam_tolerance_mm;
  std::vector<Pose> error_free;
  const std::vector<Perturbation> cases = perturbations();
  ProgressBar bar("sensitivity");
  int done = 0;
  for (const Perturbation& c : cases) {
    PreparedScene model = truth;
    c.apply(model.scene.detectors);
    auto registration = make_scene_registration(model, inside, model.scene.registration, pool);
    if (!registration.ok()) return registration.status();
    SensitivityCase row;
    row.key = c.key;
    row.name = c.name;
    for (std::size_t i = 0; i < problems.size(); ++i) {
      // The system knows only the model geometry: it gates, crops and corrects with it.
      std::vector<tracking::FrameQualityIssue> quality;
      for (std::size_t v = 0; v < problems[i].raw.size(); ++v)
        quality.push_back(tracking::assess_frame_quality(problems[i].raw[v].view(), model.roi_windows[v],
                                                         correction, tracking::FrameQualityLimits{}));
      auto frames = preprocess_scene_frames(model, problems[i].raw, correction);
      if (!frames.ok()) return frames.status();
      LFTRACK_RETURN_IF_ERROR((*registration)->set_frames(frames->frames(), frames->masks()));
      auto r = (*registration)->run(problems[i].start, *plan);
      if (!r.ok()) return r.status();
      const double tre = scene_tre(truth, r->T_room_from_ct, problems[i].gold).mean_mm;
      row.mean_tre_mm += tre / double(problems.size());
      row.max_tre_mm = std::max(row.max_tre_mm, tre);
      double added = 0;
      if (error_free.size() < problems.size()) {
        error_free.push_back(r->T_room_from_ct);
      } else {
        added = scene_tre(truth, r->T_room_from_ct, error_free[i]).mean_mm;
        row.mean_added_mm += added / double(problems.size());
      }
      auto judged = verdict_input_of(model, *inside, *frames, quality, *r);
      if (!judged.ok()) return judged.status().with_context(c.name);
      const RegistrationVerdict verdict = judge_registration(*limits, *judged);
      row.verdict.add(verdict.ok, tre < report.verdict_tolerance_mm);
      row.run_tre_mm.push_back(tre);
      row.run_added_mm.push_back(added);
      row.run_accepted.push_back(verdict.ok);
      row.run_verdict_reason.push_back(int(verdict.reason));
      bar.update(double(++done) / double(cases.size() * problems.size()));
    }
    report.cases.push_back(row);
  }
  (void)bar.finish();
  return report;
}

nlohmann::json to_json(const SensitivityReport& r) {
  nlohmann::json j;
  j["scene"] = r.scene;
  j["plan"] = r.plan;
  j["runs"] = r.runs;
  j["measure"] = r.measure;
  j["verdict_tolerance_mm"] = r.verdict_tolerance_mm;
  for (const SensitivityCase& c : r.cases) {
    j["cases"].push_back({{"key", c.key},
                          {"name", c.name},
                          {"mean_tre_mm", c.mean_tre_mm},
                          {"max_tre_mm", c.max_tre_mm},
                          {"mean_added_mm", c.mean_added_mm},
                          {"verdict", verdict_outcomes_json(c.verdict)}});
  }
  return j;
}

Status write_sensitivity_outputs(const SensitivityReport& r, const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return io_error(dir.string() + ": cannot create folder: " + ec.message());
  std::ostringstream csv;
  csv.precision(9);
  csv << "case,run,tre_mm,added_mm,accepted,verdict_reason\n";
  for (const SensitivityCase& c : r.cases)
    for (std::size_t k = 0; k < c.run_tre_mm.size(); ++k)
      csv << c.key << ',' << k << ',' << c.run_tre_mm[k] << ',' << c.run_added_mm[k] << ','
          << c.run_accepted[k] << ',' << c.run_verdict_reason[k] << '\n';
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(dir / "runs.csv", csv.str()));
  std::vector<VerdictGroup> groups;
  for (const SensitivityCase& c : r.cases) groups.push_back({c.key, c.verdict});
  char right[48];
  std::snprintf(right, sizeof right, "%.2f", r.verdict_tolerance_mm);
  GroupedBarChart chart = verdict_outcome_chart(
      "Calibration sensitivity: the registration verdict against the truth per case (right: TRE < " +
          std::string(right) + " mm)",
      groups);
  chart.key_position = "outside right top";  // clear of the bars
  chart.width = 1400;                         // seven cases
  chart.slanted_categories = true;
  if (auto drawn = draw_grouped_bars(chart, dir / "verdict.png"); !drawn.ok()) return drawn.status();
  return write_file_atomically(dir / "summary.json", to_json(r).dump(2) + "\n");  // last: the folder is complete
}

}  // namespace lftrack::studies
