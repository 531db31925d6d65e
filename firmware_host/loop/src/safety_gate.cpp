#include "lftrack/loop/safety_gate.hpp"

#include <algorithm>
#include <cmath>

namespace lftrack::loop {

const char* to_string(GateDecision d) {
  switch (d) {
    case GateDecision::kApply:
      return "APPLY";
    case GateDecision::kSkip:
      return "SKIP";
    case GateDecision::kHold:
      return "HOLD";
    case GateDecision::kStop:
      return "STOP";
  }
  return "?";
}

const char* to_string(GateReason r) {
  switch (r) {
    case GateReason::kOk:
      return "ok";
    case GateReason::kNonFinite:
      return "non-finite value";
    case GateReason::kStepTooLarge:
      return "correction step above limit";
    case GateReason::kTotalTooLarge:
      return "total correction above limit";
    case GateReason::kReadbackMismatch:
      return "actuator read-back disagrees with command";
    case GateReason::kNoResult:
      return "no registration result";
    case GateReason::kNoFrames:
      return "no complete frame pair";
    case GateReason::kActuatorFault:
      return "actuator read-back failed";
    case GateReason::kImageQuality:
      return "image quality";
    case GateReason::kJournalFailed:
      return "journal write failed";
    case GateReason::kOverruns:
      return "loop overruns";
    case GateReason::kOutsideEnvelope:
      return "registration outside the pose envelope";
    case GateReason::kCommandRefused:
      return "actuator refused the command";
    case GateReason::kNotInPlace:
      return "patient not in place: the beam withheld too long";
    case GateReason::kEnvelopeEdge:
      return "registration at the pose envelope's edge";
    case GateReason::kViewsPullApart:
      return "a view registered alone moves the target";
    case GateReason::kSurrogateStopped:
      return "surrogate stopped: no reading within surrogate.stale_ms";
    case GateReason::kSurrogateJumped:
      return "surrogate jumped: two readings further apart than surrogate.jump_mm";
    case GateReason::kSurrogateFrozen:
      return "surrogate frozen: its reading unchanged for surrogate.freeze_s";
    case GateReason::kSurrogateNotFinite:
      return "surrogate reading not finite";
    case GateReason::kModelMissed:
      return "correlation model missed twice";
    case GateReason::kModelNotReady:
      return "no correlation model for this surrogate reading";
    case GateReason::kLowSimilarity:
      return "similarity below threshold";
    case GateReason::kViewsDisagree:
      return "views disagree";
    case GateReason::kStaleFrame:
      return "stale frame";
    case GateReason::kUnpairedFrames:
      return "frames too far apart to pair";
  }
  return "?";
}

const char* to_string(BeamWithheld w) {
  switch (w) {
    case BeamWithheld::kNo:
      return "";
    case BeamWithheld::kApprovedStep:
      return "approved step beyond the step limit";
    case BeamWithheld::kActuatorTravelling:
      return "actuator still travelling";
    case BeamWithheld::kAlignment:
      return "alignment";
    case BeamWithheld::kOutOfPlace:
      return "patient out of place";
    case BeamWithheld::kModelUnconfirmed:
      return "correlation model unconfirmed";
  }
  return "?";
}

namespace {

bool finite(const GateInput& in) {
  if (!in.step.allFinite() || !in.total.allFinite() || !in.travel_left.allFinite() ||
      !in.offset_from_plan.allFinite())
    return false;
  if (!std::isfinite(in.frame_age_ms) || !std::isfinite(in.pair_skew_ms)) return false;
  if (!std::isfinite(in.readback_error_mm) || !std::isfinite(in.readback_error_deg)) return false;
  if (!std::isfinite(in.beam_off_s)) return false;
  for (int v = 0; v < in.views && v < kMaxGateViews; ++v)
    if (!std::isfinite(in.similarity[std::size_t(v)]) ||
        !std::isfinite(in.reference_similarity[std::size_t(v)]))
      return false;
  return true;
}

double angle_deg(const tracking::Vector6d& d) {
  return tracking::rad_to_deg(d.tail<3>().norm());
}

bool beyond_step_limit(const SafetyLimits& limits, const tracking::Vector6d& d) {
  return d.head<3>().cwiseAbs().maxCoeff() > limits.max_step_mm || angle_deg(d) > limits.max_step_deg;
}

// Straight-line distance, not per component: 1.9 mm on each axis is 3.3 mm out of place.
bool beyond_beam_tolerance(const SafetyLimits& limits, const tracking::Vector6d& d) {
  return d.head<3>().norm() > limits.beam_tolerance_mm || angle_deg(d) > limits.beam_tolerance_deg;
}

}  // namespace

GateReason result_quality(const SafetyLimits& limits, const GateInput& in) {
  if (!std::isfinite(in.frame_age_ms) || !std::isfinite(in.pair_skew_ms)) return GateReason::kNonFinite;
  if (in.frame_age_ms > limits.max_frame_age_ms) return GateReason::kStaleFrame;
  if (in.pair_skew_ms > limits.max_pair_skew_ms) return GateReason::kUnpairedFrames;
  double ratio_lo = 1e300, ratio_hi = -1e300;
  for (int v = 0; v < in.views && v < kMaxGateViews; ++v) {
    const double s = in.similarity[std::size_t(v)], ref = in.reference_similarity[std::size_t(v)];
    if (!std::isfinite(s) || !std::isfinite(ref)) return GateReason::kNonFinite;
    if (s < limits.min_similarity) return GateReason::kLowSimilarity;
    const double ratio = std::abs(ref) > 1e-12 ? s / ref : 1.0;
    if (ratio < limits.min_similarity_ratio) return GateReason::kLowSimilarity;
    ratio_lo = std::min(ratio_lo, ratio);
    ratio_hi = std::max(ratio_hi, ratio);
  }
  if (in.views > 1 && ratio_hi - ratio_lo > limits.max_ratio_disagreement) return GateReason::kViewsDisagree;
  return GateReason::kOk;
}

GateOutput evaluate_gate(const SafetyLimits& limits, const GateInput& in) {
  GateOutput out;
  out.consecutive_failures = in.consecutive_failures + 1;
  auto hold = [&](GateReason reason) {
    out.reason = reason;
    out.decision =
        out.consecutive_failures >= limits.fault_after_failures ? GateDecision::kStop : GateDecision::kHold;
    return out;
  };
  auto counted = [&](GateReason reason) {
    out.reason = reason;
    out.decision = out.consecutive_failures >= limits.fault_after_failures  ? GateDecision::kStop
                   : out.consecutive_failures >= limits.hold_after_failures ? GateDecision::kHold
                                                                            : GateDecision::kSkip;
    return out;
  };
  // Safety violations first: they hold whatever else is true.
  if (!finite(in) || in.views < 0 || in.views > kMaxGateViews) return hold(GateReason::kNonFinite);
  if (!in.readback_valid) return hold(GateReason::kActuatorFault);
  if (in.command_refused) return hold(GateReason::kCommandRefused);
  if (!in.journal_ok) return hold(GateReason::kJournalFailed);
  if (in.consecutive_overruns >= limits.hold_after_overruns) return hold(GateReason::kOverruns);
  if (in.readback_error_mm > limits.readback_tolerance_mm ||
      in.readback_error_deg > limits.readback_tolerance_deg)
    return hold(GateReason::kReadbackMismatch);
  if (in.model_missed) return hold(GateReason::kModelMissed);
  switch (in.surrogate_fault) {
    case SurrogateFault::kOk:
      break;
    case SurrogateFault::kJump:
      return hold(GateReason::kSurrogateJumped);
    case SurrogateFault::kFrozen:
      return hold(GateReason::kSurrogateFrozen);
    case SurrogateFault::kNotFinite:
      return hold(GateReason::kSurrogateNotFinite);
    case SurrogateFault::kNoReadings:
    case SurrogateFault::kStale:
    default:
      return hold(GateReason::kSurrogateStopped);
  }
  if (in.registration_ok) {
    if (!in.step_approved && beyond_step_limit(limits, in.step)) return hold(GateReason::kStepTooLarge);
    if (in.total.head<3>().cwiseAbs().maxCoeff() > limits.max_total_mm ||
        angle_deg(in.total) > limits.max_total_deg)
      return hold(GateReason::kTotalTooLarge);
  }
  // Quality.
  if (!in.frames_ok) return counted(GateReason::kNoFrames);
  if (!in.image_quality_ok) return counted(GateReason::kImageQuality);
  if (in.model_cycle && !in.registration_ok) {  // no pair was taken: nothing failed, a pair is next
    out.consecutive_failures = in.consecutive_failures;
    out.reason = GateReason::kModelNotReady;
    out.decision = GateDecision::kSkip;
    return out;
  }
  if (!in.registration_ok)
    return counted(in.registration_failure == GateReason::kOk ? GateReason::kNoResult : in.registration_failure);
  if (const GateReason quality = result_quality(limits, in); quality != GateReason::kOk)
    return counted(quality);
  out.decision = GateDecision::kApply;
  out.reason = GateReason::kOk;
  // A model cycle measured nothing: failed pairs before it still count towards HOLD.
  out.consecutive_failures = in.model_cycle ? in.consecutive_failures : 0;
  // The move goes out; the beam waits until the patient is in place and stays there.
  if (beyond_step_limit(limits, in.step))
    out.beam_withheld = BeamWithheld::kApprovedStep;  // only approved steps get here
  else if (beyond_beam_tolerance(limits, in.offset_from_plan))
    out.beam_withheld = BeamWithheld::kOutOfPlace;
  else if (beyond_beam_tolerance(limits, in.travel_left))
    out.beam_withheld = BeamWithheld::kActuatorTravelling;
  else if (in.model_unconfirmed)
    out.beam_withheld = BeamWithheld::kModelUnconfirmed;
  // The move would go out again, and the beam stay off again: after long enough the operator is
  // told (the couch stops; a resume approves the move again and the clock starts anew).
  if (out.beam_withheld != BeamWithheld::kNo && in.beam_off_s >= limits.max_beam_withheld_s) {
    out.beam_withheld = BeamWithheld::kNo;
    return hold(GateReason::kNotInPlace);
  }
  return out;
}

}  // namespace lftrack::loop
