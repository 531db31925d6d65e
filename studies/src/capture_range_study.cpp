#include "lftrack/studies/capture_range_study.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "lftrack/session/registration_judge.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/session/scene_verdict.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"
#include "lftrack/studies/plot.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "lftrack/studies/verdict_outcomes.hpp"
#include "lftrack/tracking/random_draws.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "quantile.hpp"

namespace lftrack::studies {

using session::locate_fiducial;
using session::make_scene_registration;
using session::make_scene_renderer;
using session::pose_at_tre;
using session::PreparedScene;
using session::preprocess_scene_frames;
using session::RegistrationSpec;
using session::scene_tre;
using session::scene_verdict_limits;
using session::verdict_input_of;
using sim_devices::make_simulated_patient;
using sim_devices::SceneImager;
using sim_devices::SimulatedPatient;

using loop::judge_registration;
using loop::RegistrationVerdict;
using loop::VerdictLimits;
using loop::VerdictReason;

using tracking::Pose;
using tracking::PoseDelta;

Result<RegistrationMethod> parse_registration_method(const std::string& text) {
  RegistrationMethod m;
  m.label = text;
  std::string rest = text;
  const auto plus = rest.find('+');
  if (plus != std::string::npos) {
    if (rest.substr(plus + 1) != "fiducial")
      return invalid_argument("method '" + text + "': only '+fiducial' may follow the measure");
    m.fiducial = true;
    rest = rest.substr(0, plus);
  }
  const auto colon = rest.find(':');
  m.plan = rest.substr(0, colon);
  if (colon != std::string::npos) m.similarity = rest.substr(colon + 1);
  if (auto p = tracking::registration_plan(m.plan); !p.ok()) return p.status().with_context("method '" + text + "'");
  const auto known = tracking::similarity_names();
  if (std::find(known.begin(), known.end(), m.similarity) == known.end())
    return invalid_argument("method '" + text + "': unknown similarity '" + m.similarity + "'");
  return m;
}

namespace {

// A start pose at initial mean TRE `target_mm` from `gold` along a random direction.
Pose perturbed_start(const PreparedScene& p, const Pose& gold, double target_mm, double max_rotation_deg,
                     std::mt19937_64& rng) {
  std::normal_distribution<double> normal(0, 1);
  const Eigen::Vector3d origin = p.registration_origin_room_mm();
  for (int attempt = 0;; ++attempt) {
    // Direction: translation and rotation (1 deg ~ 1 mm) in a random proportion.
    const Eigen::Vector3d u = tracking::draw3(normal, rng);
    const Eigen::Vector3d w = tracking::draw3(normal, rng);
    const double share = std::uniform_real_distribution<double>(0.2, 0.8)(rng);
    tracking::Vector6d dir;
    dir << u.normalized() * share, w.normalized() * tracking::deg_to_rad(1.0) * (1 - share);
    const Pose start = pose_at_tre(p, gold, dir, target_mm);
    const tracking::Vector6d v = tracking::delta_between(gold, start, origin).as_vector();
    if (tracking::rad_to_deg(v.tail<3>().norm()) <= max_rotation_deg || attempt > 100) return start;
  }
}


}  // namespace

int capture_range_shard_samples(const CaptureRangeOptions& o) {
  if (o.shards < 1 || o.shard < 1 || o.shard > o.shards || o.per_bin < o.shard) return 0;
  return (o.per_bin - o.shard) / o.shards + 1;  // samples shard-1, shard-1+n, ... below per_bin
}

std::vector<CaptureRangeSummary> summarize_capture_range(const CaptureRangeOptions& o,
                                                         const std::vector<CaptureRangeRun>& runs) {
  std::vector<CaptureRangeSummary> out;
  for (const RegistrationMethod& m : o.methods) {
    CaptureRangeSummary s;
    s.name = m.label;
    std::vector<int> bin_runs(std::size_t(o.bins), 0), bin_ok(std::size_t(o.bins), 0);
    std::vector<double> ms;
    int n = 0, ok = 0, ok_loose = 0;
    double sum_tre = 0;
    for (const CaptureRangeRun& r : runs) {
      if (r.method != m.label) continue;
      ++n;
      ms.push_back(r.ms);
      bin_runs[std::size_t(r.bin)]++;
      if (r.success_loose) ++ok_loose;
      (r.accepted ? (r.success ? s.accepted_right : s.accepted_wrong) : (r.success ? s.rejected_right : s.rejected_wrong))++;
      if (!r.success) continue;
      ++ok;
      bin_ok[std::size_t(r.bin)]++;
      sum_tre += r.tre_mean_mm;
      s.max_tre_mm = std::max(s.max_tre_mm, r.tre_max_mm);
    }
    s.success_rate = n ? double(ok) / n : 0;
    s.success_rate_loose = n ? double(ok_loose) / n : 0;
    s.mean_tre_mm = ok ? sum_tre / ok : 0;
    s.median_ms = quantile(ms, 0.5);
    s.p95_ms = quantile(ms, 0.95);
    bool run_unbroken = true;
    for (int b = 0; b < o.bins; ++b) {
      const double rate = bin_runs[std::size_t(b)] ? double(bin_ok[std::size_t(b)]) / bin_runs[std::size_t(b)] : 0;
      s.bin_success_rate.push_back(rate);
      if (run_unbroken && rate >= 0.95)
        s.capture_range_mm = (b + 1) * o.bin_width_mm;
      else
        run_unbroken = false;
    }
    out.push_back(s);
  }
  return out;
}

Result<CaptureRangeReport> run_capture_range_study(const PreparedScene& p, const CaptureRangeOptions& o,
                                                   tracking::ThreadPool* pool,
                                                   const std::function<void(double)>& progress) {
  if (o.methods.empty()) return invalid_argument("capture range: no methods");
  if (o.per_bin < 1 || o.bins < 1 || !(o.bin_width_mm > 0)) return invalid_argument("capture range: empty bins");
  if (o.shards < 1 || o.shard < 1 || o.shard > o.shards)
    return out_of_range("capture range: shard " + std::to_string(o.shard) + "/" + std::to_string(o.shards) +
                        " (k/n needs 1 <= k <= n)");
  CaptureRangeReport report;
  report.options = o;
  report.scene = p.scene.name;
  report.fingerprint = study_scene_fingerprint(p);
  if (o.anatomy_draws < 1) return invalid_argument("capture range: anatomy_draws must be >= 1");
  auto renderer = make_scene_renderer(p, o.renderer, o.light_field_dir, pool);
  if (!renderer.ok()) return renderer.status();
  // The imaged patient, one per anatomy draw (built when a sample of this shard first needs it),
  // and the detectors.
  auto imager = SceneImager::create(p, o.physics);
  if (!imager.ok()) return imager.status();
  std::vector<std::shared_ptr<const SimulatedPatient>> patients(std::size_t(o.physics.anatomy ? o.anatomy_draws : 1));
  auto patient_of = [&](int k) -> Result<std::shared_ptr<const SimulatedPatient>> {
    auto& slot = patients[std::size_t(k) % patients.size()];
    if (!slot) {
      const std::uint64_t draw = std::uint64_t(k) % patients.size();
      auto made = make_simulated_patient(p, o.physics, o.seed * 7727 + draw + 1, pool, pool);
      if (!made.ok()) return made.status();
      if (o.physics.anatomy) spdlog::info("capture range: anatomy draw {} of {} built", draw + 1, patients.size());
      slot = std::make_shared<const SimulatedPatient>(std::move(made).value());
    }
    return slot;
  };
  const bool lag = o.physics.detector && o.physics.detector->lag_fraction > 0;
  // One Registration per method (each holds its measure's prepared frames).
  std::vector<std::unique_ptr<tracking::Registration>> registrations;
  std::vector<tracking::RegistrationPlan> plans;
  std::vector<VerdictLimits> verdicts;  // per method: the scene's verdict for its measure
  for (const RegistrationMethod& m : o.methods) {
    if (m.fiducial && p.scene.fiducials.positions_ct_mm.empty())
      return failed_precondition("method " + m.label + " needs a fiducial; the scene names none");
    RegistrationSpec spec = p.scene.registration;
    spec.similarity = m.similarity;
    auto r = make_scene_registration(p, *renderer, spec, pool);
    if (!r.ok()) return r.status();
    registrations.push_back(std::move(r).value());
    plans.push_back(*tracking::registration_plan(m.plan));
    auto limits = scene_verdict_limits(p, m.similarity);
    if (!limits.ok()) return limits.status().with_context("method " + m.label);
    verdicts.push_back(*limits);
  }
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> unit(-1, 1);
  const int total = capture_range_shard_samples(o) * o.bins * int(o.methods.size());
  int done = 0;
  for (int k = 0; k < o.per_bin; ++k) {
    tracking::Vector6d g;
    for (int a = 0; a < 3; ++a) g(a) = unit(rng) * o.gold_translation_mm;
    for (int a = 3; a < 6; ++a) g(a) = tracking::deg_to_rad(unit(rng) * o.gold_rotation_deg);
    const Pose gold =
        tracking::apply_delta(p.nominal_T_room_from_ct, PoseDelta::from_vector(g), p.registration_origin_room_mm());
    if (k % o.shards != o.shard - 1) {
      // Another shard's sample: draw its starts all the same (cheap, no rendering), so that every
      // sample of every shard sees the random numbers it sees in the whole study.
      for (int b = 0; b < o.bins; ++b) {
        const double target = (b + std::uniform_real_distribution<double>(0.02, 0.98)(rng)) * o.bin_width_mm;
        perturbed_start(p, gold, target, o.max_start_rotation_deg, rng);
      }
      continue;
    }
    auto patient = patient_of(k);
    if (!patient.ok()) return patient.status();
    imager->forget_previous_frames();
    if (lag) {
      // The exposure before this one, of the patient 1 mm and 0.5 degrees away (its own random
      // numbers, so the study's draws do not depend on the physics).
      std::mt19937_64 before_rng(o.seed * 0x9e3779b97f4a7c15ULL + std::uint64_t(k));
      std::normal_distribution<double> normal;
      tracking::Vector6d step;
      step << tracking::draw3(normal, before_rng).normalized() * 1.0,
          tracking::draw3(normal, before_rng).normalized() * tracking::deg_to_rad(0.5);
      const Pose before = tracking::apply_delta(gold, PoseDelta::from_vector(step), p.registration_origin_room_mm());
      auto previous = imager->expose(**patient, before, o.seed * 100003 + std::uint64_t(k) + 50000);
      if (!previous.ok()) return previous.status();
    }
    auto raw = imager->expose(**patient, gold, o.seed * 100003 + std::uint64_t(k));
    if (!raw.ok()) return raw.status();
    std::vector<tracking::FrameQualityIssue> quality;  // the image-quality gate, as the loop runs it
    for (std::size_t v = 0; v < raw->size(); ++v)
      quality.push_back(tracking::assess_frame_quality((*raw)[v].view(), p.roi_windows[v], imager->correction(),
                                                       tracking::FrameQualityLimits{}));
    auto frames = preprocess_scene_frames(p, *raw, imager->correction());
    if (!frames.ok()) return frames.status();
    for (auto& r : registrations) LFTRACK_RETURN_IF_ERROR(r->set_frames(frames->frames(), frames->masks()));
    for (int b = 0; b < o.bins; ++b) {
      const double target = (b + std::uniform_real_distribution<double>(0.02, 0.98)(rng)) * o.bin_width_mm;
      const Pose start = perturbed_start(p, gold, target, o.max_start_rotation_deg, rng);
      const double initial = scene_tre(p, start, gold).mean_mm;
      for (std::size_t m = 0; m < o.methods.size(); ++m) {
        tracking::Registration& reg = *registrations[m];
        reg.set_fiducial(std::nullopt);
        CaptureRangeRun run;
        run.method = o.methods[m].label;
        run.bin = b;
        run.sample = k;
        run.initial_tre_mm = initial;
        bool failed = false;
        if (o.methods[m].fiducial) {
          auto located = locate_fiducial(p, *frames, start, p.scene.registration.gamma_per_mm);
          if (located.ok()) {
            reg.set_fiducial(located->term);
          } else {
            spdlog::debug("sample {} bin {}: {}", k, b, located.status().message());
          }
        }
        auto result = reg.run(start, plans[m]);
        if (!result.ok()) {
          spdlog::warn("{}: {}", run.method, result.status().message());
          failed = true;
        }
        if (!failed) {
          const tracking::Tre tre = scene_tre(p, result->T_room_from_ct, gold);
          run.tre_mean_mm = tre.mean_mm;
          run.tre_max_mm = tre.max_mm;
          run.evaluations = result->evaluations;
          run.ms = result->elapsed_ms;
          auto judged = verdict_input_of(p, **renderer, *frames, quality, *result);
          if (!judged.ok()) return judged.status();
          const RegistrationVerdict verdict = judge_registration(verdicts[m], *judged);
          run.accepted = verdict.ok;
          run.verdict_reason = int(verdict.reason);
        } else {
          run.tre_mean_mm = run.tre_max_mm = initial;
          run.verdict_reason = int(VerdictReason::kNoResult);
        }
        run.success = run.tre_mean_mm < o.success_mm;
        run.success_loose = run.tre_mean_mm < o.success_loose_mm;
        report.runs.push_back(run);
        ++done;
        if (progress) progress(double(done) / total);
      }
    }
  }
  report.summaries = summarize_capture_range(o, report.runs);
  return report;
}

Status write_capture_range_outputs(const CaptureRangeReport& report, const std::filesystem::path& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return io_error(dir.string() + ": cannot create folder: " + ec.message());
  const CaptureRangeOptions& o = report.options;
  LFTRACK_RETURN_IF_ERROR(write_capture_range_shard(report, dir, false));
  nlohmann::json j;
  j["per_bin"] = o.per_bin;
  j["bins_mm"] = nlohmann::json::array();
  for (int b = 0; b < o.bins; ++b) j["bins_mm"].push_back({b * o.bin_width_mm, (b + 1) * o.bin_width_mm});
  j["success_threshold_mm"] = o.success_mm;
  j["methods"] = nlohmann::json::array();
  for (const CaptureRangeSummary& s : report.summaries) {
    j["methods"].push_back({{"name", s.name},
                            {"success_rate", s.success_rate},
                            {"success_rate_2_5mm", s.success_rate_loose},
                            {"mean_tre_mm", s.mean_tre_mm},
                            {"max_tre_mm", s.max_tre_mm},
                            {"capture_range_mm", s.capture_range_mm},
                            {"median_ms", s.median_ms},
                            {"p95_ms", s.p95_ms},
                            {"verdict", {{"accepted_right", s.accepted_right},
                                         {"false_accepts", s.accepted_wrong},
                                         {"false_rejects", s.rejected_right},
                                         {"rejected_wrong", s.rejected_wrong}}},
                            {"bin_success_rate", s.bin_success_rate}});
  }
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(dir / "summary.json", j.dump(2) + "\n"));
  LinePlot plot;
  plot.title = "Capture range: success (final TRE < " + std::to_string(o.success_mm).substr(0, 3) + " mm)";
  plot.x_label = "initial mean TRE (mm, bin centre)";
  plot.y_label = "success rate (%)";
  plot.y_min = 0;
  plot.y_max = 105;
  for (int b = 0; b < o.bins; ++b) plot.x.push_back((b + 0.5) * o.bin_width_mm);
  for (const CaptureRangeSummary& s : report.summaries) {
    PlotSeries series{s.name, {}};
    for (double r : s.bin_success_rate) series.y.push_back(100 * r);
    plot.series.push_back(series);
  }
  auto drawn = draw_line_plot(plot, dir / "capture_range.png");
  if (!drawn.ok()) return drawn.status();
  // What the loop would do with the results: the verdict's four outcomes per method, with their
  // 95 % intervals and the count of runs.
  std::vector<VerdictGroup> groups;
  for (const CaptureRangeSummary& s : report.summaries)
    groups.push_back({s.name, {s.accepted_right, s.accepted_wrong, s.rejected_right, s.rejected_wrong}});
  const GroupedBarChart verdict = verdict_outcome_chart(
      "Capture range: the registration verdict against the truth (right: final TRE < " +
          std::to_string(o.success_mm).substr(0, 3) + " mm)",
      groups);
  auto verdict_drawn = draw_grouped_bars(verdict, dir / "verdict.png");
  if (!verdict_drawn.ok()) return verdict_drawn.status();
  return write_capture_range_description(report, dir);  // last: the folder is now a complete result
}

}  // namespace lftrack::studies
