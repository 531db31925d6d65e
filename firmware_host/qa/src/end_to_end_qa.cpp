// The hidden-target end-to-end test (daily_qa.hpp, run_end_to_end_qa).

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "daily_qa_runs.hpp"
#include "lftrack/qa/daily_qa.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/tracking/pose.hpp"

namespace lftrack::qa {
namespace {

// Where the hidden marker is, relative to where the plan puts it (mm), from the target's true
// residual at the registration origin: the anatomy's offset t and rotation vector w move a point
// `offset` from the origin by R(w) offset + t - offset.
double marker_error_mm(const loop::JournalRecord& r, const Eigen::Vector3d& offset) {
  const Eigen::Vector3d t(r.true_target_residual[0], r.true_target_residual[1], r.true_target_residual[2]);
  const Eigen::Vector3d w(r.true_target_residual[3], r.true_target_residual[4], r.true_target_residual[5]);
  return (tracking::rotation_exp(w) * offset + t - offset).norm();
}

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(std::ceil(q * static_cast<double>(v.size())) - 1);
  return v[std::min(i, v.size() - 1)];
}

}  // namespace

Result<DailyQaReport> run_end_to_end_qa(const session::PreparedScene& p, const EndToEndOptions& o,
                                        tracking::ThreadPool* pool) {
  if (!session::frames_are_simulated(p.scene) || !session::actuator_is_virtual(p.scene))
    return failed_precondition(
        "lftrack qa e2e runs in a simulated room (detectors `frames: sim`, actuator "
        "`virtual`), where the simulator knows where the hidden marker is: " +
        p.scene.source + " names real devices");
  if (!(std::isfinite(o.tolerance_mm) && o.tolerance_mm > 0))
    return invalid_argument("the end-to-end tolerance must be positive and finite");
  if (!o.marker_offset_room_mm.allFinite() || o.marker_offset_room_mm.norm() > 200)
    return invalid_argument("the hidden marker must lie within 200 mm of the registration origin");
  if (o.cycles < 100 || o.cycles > 100000)
    return invalid_argument(
        "the end-to-end test runs 100 to 100,000 cycles (its p95 needs a few dozen beam-on cycles)");
  DailyQaReport report = new_report(p, "e2e");
  report.tolerance_mm = o.tolerance_mm;
  report.marker_offset_room_mm = o.marker_offset_room_mm;
  DailyQaOptions run_options;
  run_options.light_field_dir = o.light_field_dir;
  run_options.hooks = o.hooks;
  auto run = run_tracking(p, o.cycles, run_options, pool);
  if (!run.ok()) return run.status().with_context("end-to-end test");
  for (const loop::JournalRecord& r : run->records)
    if (r.beam_permit && r.true_residual_mm >= 0)
      report.marker_error_mm.push_back(marker_error_mm(r, o.marker_offset_room_mm));
  QaCheck c;
  c.name = "e2e";
  c.tolerance = fmt::format(
      "a hidden marker {:.0f} mm from the registration origin, tracked {} cycles with the "
      "scene's set-up error and motion: within {} mm (p95) in the cycles the beam is on",
      o.marker_offset_room_mm.norm(), o.cycles, o.tolerance_mm);
  const auto& e = report.marker_error_mm;
  double mean = 0;
  for (double v : e) mean += v / static_cast<double>(e.size());
  const double p95 = quantile(e, 0.95), max = e.empty() ? 0 : *std::max_element(e.begin(), e.end());
  c.measured = fmt::format(
      "beam on in {} of {} cycles; hidden marker error mean {:.3f} mm, p95 {:.3f} mm, max "
      "{:.3f} mm; {} holds",
      e.size(), run->records.size(), mean, p95, max, run->summary.holds);
  if (e.size() < run->records.size() / 2)
    c.why = fmt::format("the beam was on in only {} of {} cycles ({})", e.size(), run->records.size(),
                        run->summary.ended);
  else if (p95 > o.tolerance_mm)
    c.why = fmt::format("the hidden marker's error p95 {:.3f} mm is beyond {} mm", p95, o.tolerance_mm);
  c.passed = c.why.empty();
  report.checks.push_back(c);
  if (o.progress)
    o.progress("e2e: " + std::string(c.passed ? "pass" : "FAIL: " + c.why) + " (" + c.measured + ")");
  return report;
}

}  // namespace lftrack::qa
