#pragma once
// The safety gate (DESIGN.md, "One cycle"): a pure function from one cycle's registration result,
// frame timing and actuator read-back to a decision. Nothing else may command motion.
//
// Two kinds of failure:
// - safety violations HOLD at once: a non-finite number anywhere, a per-cycle correction above
//   the step limit, a total correction above the total limit, an actuator read-back that
//   disagrees with the last command;
// - quality failures (no registration result, low similarity, views that disagree, a stale
//   frame, frames too far apart to be a pair) SKIP the cycle (no command, no beam) and are
//   counted: `hold_after_failures` in a row HOLD, `fault_after_failures` in a row STOP.
// Only APPLY carries a correction and allows the beam, and only with a fresh valid result.
// An APPLY still withholds the beam (BeamWithheld) while the patient is not in place: in a cycle
// whose step needed the operator's approval (beyond the step limit: the move after a resume),
// while the registered patient is further than beam_tolerance_* from the planned pose (a set-up
// move not yet made), and while the actuator, at the read-back, still had further than
// beam_tolerance_* to go to its target (an earlier large move under way, which takes the patient
// elsewhere). A patient not in place for max_beam_withheld_s (a couch that never arrives, a patient
// who has moved out of reach of the corrections) HOLDs: the operator is told, and decides.

#include <array>
#include <cstdint>

#include "lftrack/loop/imaging_on_demand.hpp"
#include "lftrack/tracking/pose.hpp"

namespace lftrack::loop {

struct SafetyLimits {
  double max_step_mm = 2.0;    // per-cycle correction, each translation component
  double max_step_deg = 2.0;   // per-cycle correction, rotation angle
  double max_total_mm = 10.0;  // from the aligned pose
  double max_total_deg = 5.0;
  double min_similarity = 0.0;          // per view, absolute (the measure's units)
  double min_similarity_ratio = 0.7;    // per view, against its value at alignment
  double max_ratio_disagreement = 0.2;  // |ratio_A - ratio_B|
  double max_frame_age_ms = 150;
  double max_pair_skew_ms = 20;
  double readback_tolerance_mm = 0.5;
  double readback_tolerance_deg = 0.5;
  // The beam is on only while the registered patient is within this of the planned pose, and the
  // actuator within this of its target: straight-line distance, and rotation angle. Tracking
  // breathing of 4.5 mm at 4 s through a couch of 0.1 s latency leaves about 0.3 mm from the plan
  // and 0.8 mm to travel; the built-in scene's registration turns the couch back and forth by up
  // to 1.3 degrees about its least-seen axis.
  double beam_tolerance_mm = 2.0;
  double beam_tolerance_deg = 2.0;
  // An APPLY that withholds the beam when the beam has been off this long in TRACK (no beam since
  // the first cycle after the alignment, or after the last beam-on APPLY, that withheld it or
  // skipped) HOLDs instead (kNotInPlace). A 10 mm set-up move at a slow couch's 2 mm/s takes 5 s.
  // Without an actuator (track and report) the same holds: a patient out of place that long is
  // set up again by the therapist.
  double max_beam_withheld_s = 10.0;
  int hold_after_failures = 3;
  int fault_after_failures = 10;
  // Overruns in a row before the loop holds: one is counted and its periods skipped; several
  // mean the host cannot keep the period, and corrections computed that late are not trusted.
  int hold_after_overruns = 3;
};

enum class GateDecision : std::uint8_t { kApply = 0, kSkip = 1, kHold = 2, kStop = 3 };
enum class GateReason : std::uint8_t {
  kOk = 0,
  kNonFinite,
  kStepTooLarge,
  kTotalTooLarge,
  kReadbackMismatch,
  kNoResult,
  kLowSimilarity,
  kViewsDisagree,
  kStaleFrame,
  kUnpairedFrames,
  kNoFrames,         // the frame source gave no complete pair (timeout, device fault, bad file)
  kActuatorFault,    // no read-back (timeout, exception, disconnected) or the actuator reports a fault
  kImageQuality,     // a frame is saturated, blank, uniform or has too many dead pixels
  kJournalFailed,    // the journal cannot be written (disk full, I/O error): nothing unrecorded moves
  kOverruns,         // hold_after_overruns cycles in a row overran their period
  kOutsideEnvelope,  // the registered pose left the scene's pose envelope (registration_verdict.hpp)
  kCommandRefused,   // the actuator refused this cycle's command: it knows of a fault, nothing moved
  kNotInPlace,       // the beam was withheld for max_beam_withheld_s: the patient does not come into place
  kEnvelopeEdge,     // the registered pose lies in the envelope's edge band (registration_verdict.hpp)
  kViewsPullApart,   // a view registered alone moves the target beyond the verdict's limit
  // Imaging on demand (imaging_on_demand.hpp):
  kSurrogateStopped,    // the surrogate (imaging_on_demand.hpp): no reading within stale_ms: HOLD
  kSurrogateJumped,     // two neighbouring readings further apart than jump_mm: HOLD
  kSurrogateFrozen,     // a reading unchanged for freeze_s: HOLD
  kSurrogateNotFinite,  // a reading that is NaN or infinite: HOLD
  kModelMissed,         // the correlation model missed a pair's registration twice in a row: HOLD
  kModelNotReady,       // a cycle without a pair whose model cannot say (not fitted, or the surrogate
                        // outside its range): SKIP, not counted (a pair is taken next)
};
// Why an APPLY kept the beam off; its correction is sent all the same.
enum class BeamWithheld : std::uint8_t {
  kNo = 0,
  kApprovedStep,        // this cycle's step is beyond the step limit (the operator approved it)
  kActuatorTravelling,  // at the read-back, the actuator was further than beam_tolerance_* from its target
  kAlignment,           // the alignment's cycle, which sends the set-up move (set by the loop, not the gate)
  kOutOfPlace,          // the registered patient is further than beam_tolerance_* from the planned pose
  kModelUnconfirmed,    // imaging on demand: the correlation model missed its last check (a pair confirms it
                        // next)
};
const char* to_string(GateDecision decision);
const char* to_string(GateReason reason);
const char* to_string(BeamWithheld withheld);

inline constexpr int kMaxGateViews = 4;

struct GateInput {
  bool frames_ok = true;  // the source delivered a complete pair this cycle
  bool image_quality_ok = true;
  bool journal_ok = true;        // the journal writes (a treatment is not run unrecorded)
  int consecutive_overruns = 0;  // cycles in a row, up to the last, that overran their period  // every frame
                                 // passed the image-quality gate (frame_quality.hpp)
  bool registration_ok = false;
  // Why there is no usable result when !registration_ok: kNoResult, or the registration verdict's
  // reason (low similarity, views disagree, outside the envelope).
  GateReason registration_failure = GateReason::kNoResult;
  tracking::Vector6d step = tracking::Vector6d::Zero();   // this cycle's correction (t mm, omega rad)
  tracking::Vector6d total = tracking::Vector6d::Zero();  // correction from the aligned pose
  int views = 0;
  std::array<double, kMaxGateViews> similarity{};            // this cycle, per view
  std::array<double, kMaxGateViews> reference_similarity{};  // at alignment, per view
  double frame_age_ms = 0;       // of the older frame of the pair, at the decision
  double pair_skew_ms = 0;       // between the two frames' timestamps
  bool readback_valid = true;    // the actuator answered the read-back and reports no fault
  // The actuator refused this cycle's command (it knows of a fault; nothing was sent or moved):
  // the loop asks the gate again with this set, and it holds.
  bool command_refused = false;
  double readback_error_mm = 0;  // actuator target against the last command
  double readback_error_deg = 0;
  // The actuator's position against its own target at the read-back: the travel it still had to
  // make (0 without a read-back), and the registered patient's offset from the planned pose at
  // the frames' exposure. Both judged against beam_tolerance_* (an APPLY's beam).
  tracking::Vector6d travel_left = tracking::Vector6d::Zero();       // target - position (mm, rad)
  tracking::Vector6d offset_from_plan = tracking::Vector6d::Zero();  // registered (mm, rad)
  int consecutive_failures = 0;  // before this cycle
  // How long the beam has been off in TRACK up to this cycle's start: from the first cycle after
  // the alignment, or after the last beam-on APPLY, that withheld it or skipped (0: none yet).
  double beam_off_s = 0;
  // Imaging on demand: this cycle's offset is the correlation model's, not a registration's (no
  // frames or similarities are judged; frame_age_ms is the surrogate reading's age), the surrogate
  // failed (SurrogateFault), the model missed twice.
  bool model_cycle = false;
  SurrogateFault surrogate_fault = SurrogateFault::kOk;
  bool model_missed = false;
  bool model_unconfirmed = false;  // the offset is a model's that missed its last check: no beam
  // The operator approved this move (the set-up move after alignment, the first move after a
  // resume): the per-cycle step limit does not apply; every other check does.
  bool step_approved = false;
};

struct GateOutput {
  GateDecision decision = GateDecision::kHold;
  GateReason reason = GateReason::kOk;
  int consecutive_failures = 0;  // after this cycle
  BeamWithheld beam_withheld = BeamWithheld::kNo;  // set only with APPLY
  bool apply() const { return decision == GateDecision::kApply; }
  // The correction goes out and the beam may be on (in TRACK: tracking_states.hpp).
  bool beam_allowed() const { return apply() && beam_withheld == BeamWithheld::kNo; }
};

GateOutput evaluate_gate(const SafetyLimits& limits, const GateInput& input);
// The gate's quality checks of a result alone (the frames' age and skew, each view's similarity
// against its floor and its alignment's, the views' agreement): kOk, or the reason the gate would
// SKIP. Imaging on demand lets a pair into the correlation model only when its result passes them.
GateReason result_quality(const SafetyLimits& limits, const GateInput& input);

}  // namespace lftrack::loop
