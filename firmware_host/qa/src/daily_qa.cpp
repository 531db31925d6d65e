#include "lftrack/qa/daily_qa.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>

#include "daily_qa_checks.hpp"
#include "daily_qa_runs.hpp"
#include "lftrack/loop/realtime_setup.hpp"
#include "lftrack/session/actuator_lock.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "room_runs.hpp"

namespace lftrack::qa {
namespace {

using tracking::Vector6d;

// Whether the detector tolerances `t` are no looser than `standard`'s.
bool no_looser(const calib::DetectorQaTolerances& t, const calib::DetectorQaTolerances& standard) {
  return t.max_dark_drift_fraction <= standard.max_dark_drift_fraction &&
         t.max_noise_ratio <= standard.max_noise_ratio && t.max_nonuniformity <= standard.max_nonuniformity &&
         t.max_new_defect_fraction <= standard.max_new_defect_fraction && t.min_frames >= standard.min_frames;
}

}  // namespace

std::vector<Vector6d> default_offset_shifts(const session::Scene& scene) {
  // Within 90 % of the envelope and of the safety gate's total correction (safety.max_total_mm,
  // _deg): a shift at the limit is refused by the gate whenever the registration reads it a hair
  // long (a room's 10 mm shift under a 10 mm total: "the loop never aligned").
  const double t =
      std::min({kStandardShiftMm, 0.9 * scene.envelope.translation_mm, 0.9 * scene.safety.max_total_mm});
  const double r = tracking::deg_to_rad(
      std::min({kStandardShiftDeg, 0.9 * scene.envelope.rotation_deg, 0.9 * scene.safety.max_total_deg}));
  std::vector<Vector6d> shifts;
  for (int axis = 0; axis < 6; ++axis) {
    Vector6d s = Vector6d::Zero();
    s(axis) = axis < 3 ? t : r;
    shifts.push_back(s);
  }
  Vector6d both;
  both << t / 2, -t / 2, t / 2, r / 2, -r / 2, r / 2;
  shifts.push_back(both);
  return shifts;
}

namespace {

// An interrupted QA's report: every check it has not made yet reported failed, "interrupted by
// the operator" (the offset test's shifts are already in it).
DailyQaReport interrupted_report(DailyQaReport report, const session::PreparedScene& p,
                                 const DailyQaOptions& o) {
  std::vector<std::string> names;
  for (const session::DetectorSpec& d : p.scene.detectors) names.push_back("detector " + d.view.name);
  names.push_back("beam");
  names.push_back("latency");
  for (const std::string& name : names) {
    const bool made = std::any_of(report.checks.begin(), report.checks.end(),
                                  [&](const QaCheck& c) { return c.name == name; });
    if (!made) report.checks.push_back(not_run(name, "not run", kInterrupted));
  }
  report.interrupted = true;
  report.standard = false;
  if (o.progress) o.progress(std::string("the QA was ") + kInterrupted + ": the checks not made fail");
  return report;
}

}  // namespace

Result<DailyQaReport> run_daily_qa(const session::PreparedScene& p, const DailyQaOptions& o,
                                   tracking::ThreadPool* pool) {
  if (!is_room(p) && !(session::frames_are_simulated(p.scene) && session::actuator_is_virtual(p.scene)))
    return failed_precondition(fmt::format(
        "lftrack qa daily runs in a simulated room (detectors `frames: sim`, actuator `virtual`) or in a "
        "room "
        "whose couch or robot is a device (actuator modbus or can) that makes the known shifts: {} has "
        "actuator "
        "{} and {} detectors, so nothing would make the shifts",
        p.scene.source, p.scene.actuator.type,
        session::frames_are_simulated(p.scene) ? "simulated" : "device"));
  if (!(o.tolerance_mm > 0 && std::isfinite(o.tolerance_mm) && o.tolerance_deg > 0 &&
        std::isfinite(o.tolerance_deg)))
    return invalid_argument("the QA's tolerances must be positive and finite");
  if (o.latency_cycles < 0 || (o.latency_cycles > 0 && o.latency_cycles < 20))
    return invalid_argument("the latency chain runs 0 (not at all: the QA fails) or at least 20 cycles");
  LFTRACK_RETURN_IF_ERROR(check_detector_qa_options(p, o.detectors));
  // A room: no other program drives its couch while the QA runs (a second QA, a treatment), and
  // the QA's own runs share the lock.
  std::shared_ptr<const session::ActuatorLock> couch_lock;
  if (is_room(p)) {
    auto lock = session::ActuatorLock::acquire(p.scene);
    if (!lock.ok()) return lock.status();
    couch_lock = std::move(lock).value();
  }
  const auto interrupted = [&] { return qa::interrupted(o); };
  DailyQaReport report = new_report(p, "daily");
  report.tolerance_mm = o.tolerance_mm;
  report.tolerance_deg = o.tolerance_deg;
  auto say = [&](const std::string& line) {
    if (o.progress) o.progress(line);
  };

  const std::vector<Vector6d> shifts = o.shifts.empty() ? default_offset_shifts(p.scene) : o.shifts;
  // TG-135's shifts are 10 mm and 1 degree; an envelope that scales them below half of that makes
  // a QA whose shifts the tolerances would nearly cover: not the standard QA.
  double largest_mm = 0, largest_deg = 0;
  for (const Vector6d& shift : shifts) {
    largest_mm = std::max(largest_mm, translation_mm(shift));
    largest_deg = std::max(largest_deg, largest_rotation_deg(shift));
  }
  report.standard = o.shifts.empty() && largest_mm >= kStandardShiftMm / 2 &&
                    largest_deg >= kStandardShiftDeg / 2 && o.tolerance_mm <= kStandardToleranceMm &&
                    o.tolerance_deg <= kStandardToleranceDeg && o.latency_cycles >= kStandardLatencyCycles &&
                    no_looser(o.detectors.tolerances, calib::DetectorQaTolerances{}) &&
                    (o.latency_tolerance_ms <= 0 || o.latency_tolerance_ms <= p.scene.loop.period_ms);
  // Nothing has been moved yet: an interruption now is a QA not made, with no report (a failed
  // one would void the day's earlier pass).
  if (interrupted())
    return failed_precondition(std::string(kInterrupted) +
                               " before the QA began: nothing was moved, no report made");
  std::string stopped;  // a room: why the offset test stopped (the couch may not be where it thinks)
  for (const Vector6d& shift : shifts) {
    if (stopped.empty() && interrupted()) stopped = kInterrupted;
    if (!stopped.empty()) {
      OffsetResult skipped;
      skipped.shift = shift;
      skipped.why = "not run: " + stopped;
      report.offsets.push_back(skipped);
      say("offset " + shift_text(shift) + ": not run");
      continue;
    }
    auto run = run_offset(p, shift, o.offset_cycles, o, pool);
    const bool cut_short = interrupted() && (!run.ok() || int(run->records.size()) < o.offset_cycles);
    if (cut_short) {  // the shift is not judged; a room's couch goes back to where it stood before it
      OffsetResult cut;
      cut.shift = shift;
      cut.why = run.ok() ? std::string(kInterrupted) : run.status().message();
      if (run.ok() && run->couch_before) {
        const Status back = move_couch_to(p, *run->couch_before, couch_move_timeout_s(p.scene, shift));
        cut.why += back.ok() ? ": the couch is back where it stood before the shift"
                             : ": the couch could not be sent back: " + back.message();
      }
      report.offsets.push_back(cut);
      stopped = kInterrupted;
      say("offset " + shift_text(shift) + ": " + cut.why);
      continue;
    }
    if (run.ok()) {
      report.offsets.push_back(judge_offset(shift, *run, o));
      // A room's couch sent back to where it stood before a shift that failed: the next shift is
      // made from there (and aligned first), never on top of this one.
      if (!report.offsets.back().passed && run->couch_before) {
        const Status back = move_couch_to(p, *run->couch_before, couch_move_timeout_s(p.scene, shift));
        if (!back.ok()) stopped = "after a failed shift the couch could not be sent back: " + back.message();
      }
    } else if (is_room(p)) {  // the room's couch or devices failed the shift: the shift's failure
      OffsetResult failed;
      failed.shift = shift;
      failed.why = run.status().message();
      report.offsets.push_back(failed);
      stopped = "the shift before failed (" + failed.why + ")";
    } else {
      return run.status().with_context("offset test, shift " + shift_text(shift));
    }
    const OffsetResult& r = report.offsets.back();
    if (r.aligned)
      say(fmt::format("offset {}: {} (alignment off by {:.3f} mm, {:.3f} deg; couch {:.3f} mm, {:.3f} deg){}",
                      shift_text(shift), r.passed ? "pass" : "FAIL", r.registration_error_mm,
                      r.registration_error_deg, r.couch_error_mm, r.couch_error_deg,
                      r.passed ? "" : ": " + r.why));
    else
      say(fmt::format("offset {}: FAIL (not measured): {}", shift_text(shift), r.why));
  }
  report.checks.push_back(offset_check(report.offsets, o));
  if (interrupted()) return interrupted_report(std::move(report), p, o);

  for (QaCheck& c : detector_checks(p, o.detectors, o.progress)) report.checks.push_back(std::move(c));
  if (auto note = simulated_detector_note(p, o.detectors)) report.not_checked.push_back(*note);

  constexpr int kDarkFrom = 15, kDarkTo = 25;
  if (interrupted()) return interrupted_report(std::move(report), p, o);
  auto dark = run_dark_detectors(p, std::max(o.beam_cycles, kDarkTo + 5), kDarkFrom, kDarkTo, o, pool);
  if (interrupted()) return interrupted_report(std::move(report), p, o);
  if (dark.ok())
    report.checks.push_back(beam_check(*dark, kDarkFrom, p.scene.safety.hold_after_failures));
  else if (is_room(p))  // a room's devices that fail the run fail the check; the report is written
    report.checks.push_back(not_run("beam", "the beam-permit run", dark.status().message()));
  else
    return dark.status().with_context("beam-permit test");
  say("beam: " + std::string(report.checks.back().passed ? "pass" : "FAIL: " + report.checks.back().why));

  if (o.latency_cycles > 0) {
    const double tolerance = o.latency_tolerance_ms > 0 ? o.latency_tolerance_ms : p.scene.loop.period_ms;
    // As the room runs: the scene's real-time set-up applied first (enforce), then a pool made
    // after it, whose workers inherit the cycle's policy as the service's do. The QA's own thread
    // keeps it to the end (the reports are written after).
    Result<loop::RealtimeReport> rt = loop::realtime_not_applied("loop.realtime.mode: ignore");
    if (p.scene.loop.realtime.enforce) rt = loop::apply_realtime_setup(p.scene.loop.realtime);
    if (!rt.ok()) {
      QaCheck c;
      c.name = "latency";
      c.tolerance = "the scene's real-time set-up applied, then a real-clock run";
      c.measured = "not run";
      c.why = rt.status().message();
      report.checks.push_back(c);
    } else {
      tracking::ThreadPool rt_pool(pool->size());
      auto real = run_real_clock(p, o.latency_cycles, o, &rt_pool);
      if (interrupted()) return interrupted_report(std::move(report), p, o);
      if (real.ok()) {
        report.checks.push_back(latency_check(*real, tolerance, o.latency_cycles));
        report.checks.back().measured += "; real-time set-up: " + rt->summary();
      } else if (is_room(p)) {
        report.checks.push_back(not_run("latency", "a real-clock run", real.status().message()));
      } else {
        return real.status().with_context("latency test");
      }
    }
    const QaCheck& latency = report.checks.back();
    say("latency: " + (latency.passed ? std::string("pass") : "FAIL: " + latency.why) + " (" +
        latency.measured + ")");
  } else {
    QaCheck c;
    c.name = "latency";
    c.why = "not run (--latency-cycles 0)";
    c.measured = "not run";
    c.tolerance = "a real-clock run";
    report.checks.push_back(c);
    say("latency: FAIL: not run (--latency-cycles 0)");
  }
  return report;
}

}  // namespace lftrack::qa
