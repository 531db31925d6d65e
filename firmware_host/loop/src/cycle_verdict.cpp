// The cycle's judge stage (loop_impl.hpp): the verdict on the registration's result
// (registration_verdict.hpp), the check of each frame against the DRR at the result and of each
// view registered alone included. The gate (cycle_stages.cpp) then judges the move.

#include <limits>

#include "loop_impl.hpp"

namespace lftrack::loop {

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

// Judge: the verdict on the registration, before anything takes its result (control feeds an
// accepted result to the predictor, the correlation model and the alignment's reference, so a
// rejected one must never reach it). It judges the alignment, whose result is the set-up move (no
// step limit), and, with settings.judge_tracking (a commissioned scene: its floors were measured
// on tracking frames), every tracking cycle, the NCC check (a DRR per view) included: the two
// floors were chosen together, so neither is judged without the other (the check costs 0.34 ms
// median, 2.5 ms p95 a cycle on the lumbar clinical scene). Uncommissioned scenes' tracking
// cycles are judged by the gate's ratios against the alignment only: on a loaded host the
// measures' default floors skipped good time-boxed tracking registrations (closed-loop tests
// under ctest -j2). A rejected registration is the gate's registration failure, with the
// verdict's reason.
void TrackingLoop::Impl::judge(CycleState& c) {
  if (!c.registered || !settings.verdict || (!c.aligning && !settings.judge_tracking)) return;
  const std::size_t views = pair.frames.size();
  VerdictInput judged;
  judged.views = static_cast<int>(views);
  judged.stop = result.stop;
  judged.pose_finite = result.T_room_from_ct.matrix().allFinite();
  for (std::size_t v = 0; v < views && v < std::size_t(kMaxVerdictViews); ++v)
    judged.similarity[v] = result.view_similarity[v];
  judged.delta_from_nominal =
      tracking::delta_between(nominal, result.T_room_from_ct, origin_room).as_vector();
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
      judged.check_ncc[v] = rendered ? masked_ncc(line_integral[v].view(), valid[v].view(),
                                                  check_drr[v].view(), check_valid[v].view())
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
  const double budget_ms =
      c.aligning ? kUnlimitedStageMs
                 : clock->stage_budget_ms(ms_between(monotonic_now_ns(), c.start_ns + period_ns) -
                                          0.25 * settings.loop.period_ms);
  const std::int64_t started_ns = monotonic_now_ns();
  bool complete = false;
  const int views = parts.view_agreement->views();
  if (budget_ms >= 1 && parts.view_agreement->set_frames(frame_views, mask_views).ok() &&
      parts.view_agreement
          ->measure(result.T_room_from_ct, budget_ms / views, &judged.view_shift_mm, &complete)
          .ok() &&
      complete) {
    judged.has_view_shift = true;
    verdict = judge_registration(*settings.verdict, judged);
    c.view_checked = true;
    view_check_due = false;
    tracking_cycles_since_view_check = 0;
  } else {
    c.view_check_out_of_time = true;  // stays due: tried again next cycle
    if (c.aligning) {                 // not for want of time: the set-up move is not made without the check
      verdict.ok = false;
      verdict.reason = VerdictReason::kNoResult;
    }
  }
  c.view_check_ms = ms_between(started_ns, monotonic_now_ns());
}

}  // namespace lftrack::loop
