#include "lftrack/qa/daily_qa.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>

#include "daily_qa_runs.hpp"
#include "lftrack/host/scene_devices.hpp"
#include "lftrack/host/scene_fingerprint.hpp"
#include "lftrack/loop/tracking_states.hpp"

namespace lftrack::qa {
namespace {

using host::JournalRecord;
using host::TrackingState;
using tracking::Vector6d;

constexpr double kPi = 3.14159265358979323846;
double degrees(double rad) {
  return rad * 180.0 / kPi;
}

double translation_mm(const Vector6d& v) {
  return v.head<3>().norm();
}
double largest_rotation_deg(const Vector6d& v) {
  return degrees(v.tail<3>().cwiseAbs().maxCoeff());
}

Vector6d from(const double (&values)[6]) {
  Vector6d v;
  for (int i = 0; i < 6; ++i) v(i) = values[i];
  return v;
}

std::string shift_text(const Vector6d& v) {
  return fmt::format("({:+.1f}, {:+.1f}, {:+.1f}) mm, ({:+.2f}, {:+.2f}, {:+.2f}) deg", v(0), v(1), v(2),
                     degrees(v(3)), degrees(v(4)), degrees(v(5)));
}

// Now in UTC: the ISO 8601 time and the date it counts for.
void utc_now(std::string* iso, std::string* date) {
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  ::gmtime_r(&now, &tm);
  char text[64];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &tm);
  *iso = text;
  std::strftime(text, sizeof text, "%Y-%m-%d", &tm);
  *date = text;
}

// One shift's run judged: the alignment's registration against the shift, the couch's read-back
// against the move that undoes it, and the last registration against nothing left to correct.
OffsetResult judge_offset(const Vector6d& shift, const RecordedRun& run, const DailyQaOptions& o) {
  OffsetResult r;
  r.shift = shift;
  const auto align = std::find_if(run.records.begin(), run.records.end(), [](const JournalRecord& c) {
    return c.previous_state == static_cast<std::uint8_t>(TrackingState::kAlign) &&
           c.state == static_cast<std::uint8_t>(TrackingState::kTrack);
  });
  if (align == run.records.end()) {
    r.why = "the loop never aligned (" +
            (run.summary.ended.empty() ? std::string("no TRACK") : run.summary.ended) + ")";
    return r;
  }
  r.aligned = true;
  r.registered = from(align->pose_delta);
  r.registration_error_mm = translation_mm(r.registered - shift);
  r.registration_error_deg = largest_rotation_deg(r.registered - shift);
  // The couch undoes the shift: its read-back moves by -shift from where it stood at the start.
  const JournalRecord& last = run.records.back();
  r.couch_moved = -(from(last.readback) - from(run.records.front().readback));
  r.couch_error_mm = translation_mm(r.couch_moved - shift);
  r.couch_error_deg = largest_rotation_deg(r.couch_moved - shift);
  r.final_offset_mm = translation_mm(from(last.pose_delta));
  const bool held = run.summary.holds > 0 || run.summary.faults > 0;
  if (r.registration_error_mm > o.tolerance_mm || r.registration_error_deg > o.tolerance_deg)
    r.why = fmt::format("the alignment found {} for a shift of {}: off by {:.2f} mm, {:.2f} deg",
                        shift_text(r.registered), shift_text(shift), r.registration_error_mm,
                        r.registration_error_deg);
  else if (r.couch_error_mm > o.tolerance_mm || r.couch_error_deg > o.tolerance_deg)
    r.why = fmt::format("the couch moved {} in {} cycles to undo {}: off by {:.2f} mm, {:.2f} deg",
                        shift_text(r.couch_moved), run.records.size(), shift_text(shift), r.couch_error_mm,
                        r.couch_error_deg);
  else if (r.final_offset_mm > o.tolerance_mm)
    r.why = fmt::format("after the couch's move the phantom is still {:.2f} mm off", r.final_offset_mm);
  else if (held)
    r.why = "the loop held: " + run.summary.ended;
  r.passed = r.why.empty();
  return r;
}

QaCheck offset_check(const std::vector<OffsetResult>& offsets, const DailyQaOptions& o) {
  QaCheck c;
  c.name = "offset";
  c.tolerance = fmt::format(
      "each of {} known shifts found by the alignment and moved by the couch within {} mm "
      "and {} deg; the phantom back within {} mm",
      offsets.size(), o.tolerance_mm, o.tolerance_deg, o.tolerance_mm);
  double worst_mm = 0, worst_deg = 0;
  int passed = 0;
  for (const OffsetResult& r : offsets) {
    worst_mm = std::max({worst_mm, r.registration_error_mm, r.couch_error_mm});
    worst_deg = std::max({worst_deg, r.registration_error_deg, r.couch_error_deg});
    if (r.passed)
      ++passed;
    else if (c.why.empty())
      c.why = "shift " + shift_text(r.shift) + ": " + r.why;
  }
  c.measured = fmt::format("{} of {} shifts passed; largest error {:.3f} mm, {:.3f} deg", passed,
                           offsets.size(), worst_mm, worst_deg);
  c.passed = !offsets.empty() && passed == static_cast<int>(offsets.size());
  if (offsets.empty()) c.why = "no shift was run";
  return c;
}

// The detectors dark in [dark_from, dark_to): a HOLD, the beam off in every HOLD cycle and, with
// no operator, in every cycle after it; on before the fault (the permit path is live).
QaCheck beam_check(const RecordedRun& run, int dark_from) {
  QaCheck c;
  c.name = "beam";
  c.tolerance =
      "the beam permitted while tracking, withheld in every HOLD cycle when the detectors go dark, and "
      "never permitted again without an operator";
  int permitted_before = 0, hold_cycles = 0, permitted_in_hold = 0, permitted_after = 0;
  std::int64_t first_hold = -1;
  for (const JournalRecord& r : run.records) {
    const bool hold = r.state == static_cast<std::uint8_t>(TrackingState::kHold);
    if (hold && first_hold < 0) first_hold = static_cast<std::int64_t>(r.cycle);
    if (hold) ++hold_cycles;
    if (hold && r.beam_permit) ++permitted_in_hold;
    if (first_hold >= 0 && r.beam_permit) ++permitted_after;
    if (first_hold < 0 && static_cast<std::int64_t>(r.cycle) < dark_from && r.beam_permit) ++permitted_before;
  }
  c.measured = first_hold < 0
                   ? fmt::format("beam on in {} cycles before the fault; no HOLD in {} cycles",
                                 permitted_before, run.records.size())
                   : fmt::format(
                         "beam on in {} cycles before the fault; HOLD from cycle {}, {} HOLD cycles, beam on "
                         "in {} of them and in {} cycles after the first",
                         permitted_before, first_hold, hold_cycles, permitted_in_hold, permitted_after);
  if (permitted_before == 0)
    c.why = "the beam was never permitted while tracking: the permit path is not live";
  else if (first_hold < 0)
    c.why = "the detectors went dark and the loop did not HOLD";
  else if (permitted_in_hold > 0 || permitted_after > 0)
    c.why = "the beam was permitted in a HOLD or after it without an operator";
  c.passed = c.why.empty();
  return c;
}

QaCheck latency_check(const RecordedRun& run, double tolerance_ms, int cycles) {
  QaCheck c;
  c.name = "latency";
  c.tolerance = fmt::format(
      "{} cycles on the real clock: no overrun, exposure to acknowledgement p99 within {:.0f} "
      "ms, the control socket answering `status` with the loop's state",
      cycles, tolerance_ms);
  const auto& latency = run.summary.command_latency;
  const double p99 = latency ? latency->p99_ms : -1;
  c.measured =
      fmt::format("{} cycles, {} overruns, exposure to acknowledgement p99 {}; control socket: {}",
                  run.summary.cycles, run.summary.overruns,
                  latency ? fmt::format("{:.1f} ms over {} commands", p99, latency->commands)
                          : std::string("no command acknowledged"),
                  run.control_reply.empty()
                      ? std::string("no answer")
                      : fmt::format("\"{}\"", run.control_reply.substr(0, run.control_reply.find('\n'))));
  if (run.control_reply.rfind("TRACK", 0) != 0)
    c.why = run.control_reply.empty()
                ? std::string("the control socket did not answer `status`")
                : fmt::format("the control socket answered `{}`, not TRACK",
                              run.control_reply.substr(0, run.control_reply.find('\n')));
  else if (run.summary.overruns > 0)
    c.why = fmt::format("{} cycles overran their period", run.summary.overruns);
  else if (!latency || latency->commands == 0)
    c.why = "no command was acknowledged";
  else if (p99 > tolerance_ms)
    c.why = fmt::format("exposure to acknowledgement p99 {:.1f} ms is beyond {:.0f} ms", p99, tolerance_ms);
  c.passed = c.why.empty();
  return c;
}

}  // namespace

bool DailyQaReport::passed() const {
  return !checks.empty() &&
         std::all_of(checks.begin(), checks.end(), [](const QaCheck& c) { return c.passed; });
}

std::vector<Vector6d> default_offset_shifts(const host::Scene& scene) {
  const double t = std::min(10.0, 0.9 * scene.envelope.translation_mm);
  const double r = std::min(1.0, 0.9 * scene.envelope.rotation_deg) * kPi / 180.0;
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

Result<DailyQaReport> run_daily_qa(const host::PreparedScene& p, const DailyQaOptions& o,
                                   tracking::ThreadPool* pool) {
  if (!host::frames_are_simulated(p.scene) || !host::actuator_is_virtual(p.scene))
    return failed_precondition(
        "lftrack qa daily runs in a simulated room (detectors `frames: sim`, actuator `virtual`): " +
        p.scene.source +
        " names real devices, and a QA that moves a real couch by known shifts is not built yet");
  if (!(o.tolerance_mm > 0 && std::isfinite(o.tolerance_mm) && o.tolerance_deg > 0 &&
        std::isfinite(o.tolerance_deg)))
    return invalid_argument("the QA's tolerances must be positive and finite");
  DailyQaReport report;
  report.scene_name = p.scene.name;
  report.scene_source = p.scene.source;
  report.room_fingerprint = host::to_hex(host::room_fingerprint(p.scene));
  utc_now(&report.started_utc, &report.date_utc);
  report.tolerance_mm = o.tolerance_mm;
  report.tolerance_deg = o.tolerance_deg;
  report.not_checked = {
      "the detectors' image quality against their calibration (dark level, gain uniformity, defect count "
      "growth): "
      "not built; simulated detectors have no calibration to drift from"};
  auto say = [&](const std::string& line) {
    if (o.progress) o.progress(line);
  };

  const std::vector<Vector6d> shifts = o.shifts.empty() ? default_offset_shifts(p.scene) : o.shifts;
  for (const Vector6d& shift : shifts) {
    auto run = run_offset(p, shift, o.offset_cycles, o, pool);
    if (!run.ok()) return run.status().with_context("offset test, shift " + shift_text(shift));
    report.offsets.push_back(judge_offset(shift, *run, o));
    const OffsetResult& r = report.offsets.back();
    say(fmt::format("offset {}: {} (alignment off by {:.3f} mm, {:.3f} deg; couch {:.3f} mm){}",
                    shift_text(shift), r.passed ? "pass" : "FAIL", r.registration_error_mm,
                    r.registration_error_deg, r.couch_error_mm, r.passed ? "" : ": " + r.why));
  }
  report.checks.push_back(offset_check(report.offsets, o));

  constexpr int kDarkFrom = 15, kDarkTo = 25;
  auto dark = run_dark_detectors(p, std::max(o.beam_cycles, kDarkTo + 5), kDarkFrom, kDarkTo, o, pool);
  if (!dark.ok()) return dark.status().with_context("beam-permit test");
  report.checks.push_back(beam_check(*dark, kDarkFrom));
  say("beam: " + std::string(report.checks.back().passed ? "pass" : "FAIL: " + report.checks.back().why));

  if (o.latency_cycles > 0) {
    const double tolerance = o.latency_tolerance_ms > 0 ? o.latency_tolerance_ms : p.scene.loop.period_ms;
    auto real = run_real_clock(p, o.latency_cycles, o, pool);
    if (!real.ok()) return real.status().with_context("latency test");
    report.checks.push_back(latency_check(*real, tolerance, o.latency_cycles));
    say("latency: " +
        std::string(report.checks.back().passed ? "pass" : "FAIL: " + report.checks.back().why));
  } else {
    QaCheck c;
    c.name = "latency";
    c.why = "not run (--latency-cycles 0)";
    c.measured = "not run";
    c.tolerance = "a real-clock run";
    report.checks.push_back(c);
  }
  return report;
}

}  // namespace lftrack::qa
