// The cycle's register stage (cycle_stages.cpp has the others): the registration, cold in ALIGN
// and warm in TRACK, and the verdict that judges it, each view registered alone included.

#include <limits>

#include "lftrack/loop/cycle_schedule.hpp"
#include "loop_impl.hpp"

namespace lftrack::host {

using tracking::Pose;
using tracking::PoseDelta;

namespace {

// The gate's reason for a registration the verdict rejected.
GateReason gate_reason_of(VerdictReason r) {
  switch (r) {
    case VerdictReason::kLowSimilarity:
      return GateReason::kLowSimilarity;
    case VerdictReason::kViewsDisagree:
      return GateReason::kViewsDisagree;
    case VerdictReason::kViewsPullApart:
      return GateReason::kViewsPullApart;
    case VerdictReason::kOutsideEnvelope:
      return GateReason::kOutsideEnvelope;
    case VerdictReason::kEnvelopeEdge:
      return GateReason::kEnvelopeEdge;
    case VerdictReason::kImageQuality:
      return GateReason::kImageQuality;
    default:
      return GateReason::kNoResult;
  }
}

}  // namespace

// Register: cold in ALIGN, warm from the last pose (moved with the couch) otherwise. The verdict
// judges the alignment, whose result is the set-up move (no step limit), and, with
// settings.judge_tracking (a commissioned scene: its floors were measured on tracking frames),
// every tracking cycle, the NCC check (a DRR per view) included: the two floors were chosen
// together, so neither is judged without the other (the check costs 0.34 ms median, 2.5 ms p95 a
// cycle on the lumbar clinical scene). Uncommissioned scenes' tracking cycles are judged by the
// gate's ratios against the alignment only: on a loaded host the measures' default floors skipped
// good time-boxed tracking registrations (closed-loop tests under ctest -j2).
void TrackingLoop::Impl::register_pair(CycleState& c) {
  const bool tracked_state =
      c.state == TrackingState::kAlign || c.state == TrackingState::kTrack || c.state == TrackingState::kHold;
  if (!c.frames_usable || !tracked_state) return;
  Pose start = nominal;
  if (!c.aligning && have_registration)
    start = tracking::apply_delta(last_registered, PoseDelta::from_vector(couch_position - couch_at_last_registration),
                                  origin_room);
  // Imaging on demand: a pair a second after the last finds a breathing target elsewhere; the
  // correlation model's offset at the pair's surrogate, on the couch as it stands, is nearer.
  tracking::Vector6d model_patient_offset;
  if (!c.aligning && model_offset(c, &model_patient_offset))
    start = tracking::apply_delta(Pose::Identity(), PoseDelta::from_vector(couch_position), origin_room) *
            tracking::apply_delta(nominal, PoseDelta::from_vector(model_patient_offset), origin_room);
  // The budget is wall time, so on the simulated clock, whose runs must repeat bit for bit
  // whatever the host's load, a tracking registration is not cut short either: a search cut at a
  // load-dependent moment made two runs of one seed diverge (ClosedLoop.TwoRunsOfOneSeed...).
  const double budget_ms = c.aligning || settings.simulated_clock ? 1e12 : settings.loop.registration_budget_ms;
  const RegistrationStage stage = c.aligning ? RegistrationStage::kAlign : RegistrationStage::kTrack;
  c.registered = parts.registration->run(start, stage, budget_ms, &result).ok() && result_is_finite();
  c.registration_ran = true;
  c.evaluations = static_cast<std::uint32_t>(result.evaluations);
  c.registration_ms = result.elapsed_ms;
  if (!c.registered || !settings.verdict || (!c.aligning && !settings.judge_tracking)) return;
  const std::size_t views = pair.frames.size();
  VerdictInput judged;
  judged.views = static_cast<int>(views);
  judged.stop = result.stop;
  judged.pose_finite = result.T_room_from_ct.matrix().allFinite();
  for (std::size_t v = 0; v < views && v < std::size_t(kMaxVerdictViews); ++v)
    judged.similarity[v] = result.view_similarity[v];
  judged.delta_from_nominal = tracking::delta_between(nominal, result.T_room_from_ct, origin_room).as_vector();
  // Each frame against the DRR at the result: what catches A/B-swapped detectors.
  if (parts.check_renderer != nullptr) {
    const std::int64_t check_started_ns = monotonic_now_ns();
    judged.has_check_ncc = true;
    for (std::size_t v = 0; v < views && v < std::size_t(kMaxVerdictViews); ++v) {
      tracking::RenderExtras extras;
      extras.valid = check_valid[v].view();
      const bool rendered = parts.check_renderer
                                ->render(result.T_room_from_ct, parts.geometry.views[v],
                                         parts.geometry.roi_windows[v], check_drr[v].view(), &extras)
                                .ok();
      judged.check_ncc[v] = rendered ? masked_ncc(line_integral[v].view(), valid[v].view(), check_drr[v].view(),
                                                  check_valid[v].view())
                                     : std::numeric_limits<double>::quiet_NaN();
    }
    c.verdict_checked = true;
    c.verdict_check_ms = ms_between(check_started_ns, monotonic_now_ns());
  }
  RegistrationVerdict verdict = judge_registration(*settings.verdict, judged);
  if (verdict.ok) check_views(c, judged, verdict);
  if (!verdict.ok) {
    c.registered = false;
    c.gate_input.registration_failure = gate_reason_of(verdict.reason);
  }
}

// Each view registered alone from an accepted result (view_agreement.hpp): at every alignment,
// whatever it takes (the set-up move is never made without it; an alignment that takes longer
// than the frames' age limit is skipped by the gate and tried again with the next pair), and on
// every Nth tracking cycle of a judged scene, within what is left of the cycle less a quarter
// period for the stages after it (real clock). A tracking check that does not fit is not a
// verdict: it is counted and stays due for the next cycle.
void TrackingLoop::Impl::check_views(CycleState& c, VerdictInput& judged, RegistrationVerdict& verdict) {
  if (parts.view_agreement == nullptr) return;
  if (c.aligning) {
    view_check_due = true;
  } else {
    if (!settings.judge_tracking) return;
    if (settings.view_check_every > 0 && ++tracking_cycles_since_view_check >= settings.view_check_every)
      view_check_due = true;
  }
  if (!view_check_due) return;
  double budget_ms = 1e12;
  if (!settings.simulated_clock && !c.aligning)
    budget_ms = ms_between(monotonic_now_ns(), c.start_ns + period_ns) - 0.25 * settings.loop.period_ms;
  const std::int64_t started_ns = monotonic_now_ns();
  bool complete = false;
  const int views = parts.view_agreement->views();
  if (budget_ms >= 1 && parts.view_agreement->set_frames(frame_views, mask_views).ok() &&
      parts.view_agreement->measure(result.T_room_from_ct, budget_ms / views, &judged.view_shift_mm, &complete).ok() &&
      complete) {
    judged.has_view_shift = true;
    verdict = judge_registration(*settings.verdict, judged);
    c.view_checked = true;
    view_check_due = false;
    tracking_cycles_since_view_check = 0;
  } else {
    c.view_check_out_of_time = true;  // stays due: tried again next cycle
    if (c.aligning) {  // not for want of time: the set-up move is not made without the check
      verdict.ok = false;
      verdict.reason = VerdictReason::kNoResult;
    }
  }
  c.view_check_ms = ms_between(started_ns, monotonic_now_ns());
}

}  // namespace lftrack::host
