#include "lftrack/chaos/chaos_invariants.hpp"

#include <cmath>
#include <string>

#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/tracking_states.hpp"

namespace lftrack::chaos {

namespace {

constexpr double kTolerance = 1e-6;  // mm and degrees: the loop's own sums against ours

std::uint8_t code(TrackingState s) {
  return static_cast<std::uint8_t>(s);
}
std::uint8_t code(OperatorCommand c) {
  return static_cast<std::uint8_t>(1 + static_cast<int>(c));  // JournalRecord::operator_command
}

double translation_mm(const tracking::Vector6d& v) {
  return v.head<3>().cwiseAbs().maxCoeff();  // per component, as the gate limits it
}
double angle_deg(const tracking::Vector6d& v) {
  return tracking::rad_to_deg(v.tail<3>().norm());
}

// The gate's limits, written again here: the checker shares no code with the loop's decisions.
// NaN is beyond.
bool beyond(double mm, double deg, double most_mm, double most_deg) {
  return !(mm <= most_mm + kTolerance) || !(deg <= most_deg + kTolerance);
}
bool beyond_step_limit(const SafetyLimits& limits, const tracking::Vector6d& v) {
  return beyond(translation_mm(v), angle_deg(v), limits.max_step_mm, limits.max_step_deg);
}
// The beam's tolerance is a straight-line distance, not per component.
double distance_mm(const tracking::Vector6d& v) {
  return v.head<3>().norm();
}
bool beyond_beam_tolerance(const SafetyLimits& limits, const tracking::Vector6d& v) {
  return beyond(distance_mm(v), angle_deg(v), limits.beam_tolerance_mm, limits.beam_tolerance_deg);
}
std::string mm_deg(double mm, double deg) {
  return std::to_string(mm) + " mm / " + std::to_string(deg) + " deg";
}

bool held(std::uint8_t state) {
  return state == code(TrackingState::kHold) || state == code(TrackingState::kFault);
}

}  // namespace

void InvariantChecker::check(const JournalRecord& r, const ActuatorCalls& calls,
                             const CycleInjection& injected, const OperatorAction& action,
                             std::vector<std::string>* out) {
  const auto fail = [&](const std::string& what) {
    out->push_back(*injected.what != '\0' ? what + " (injected: " + injected.what + ")" : what);
  };
  const bool sent = r.command_sent != 0;
  const bool beam = r.beam_permit != 0;
  const bool resumed = r.operator_command == code(OperatorCommand::kResume);
  const bool reset = r.operator_command == code(OperatorCommand::kReset);
  // The cycle ran in ALIGN (its cold registration is not judged for overruns): it began there, or
  // a reset took it there (through IDLE), or a resume did, from a HOLD before any alignment.
  const bool ran_in_align =
      r.previous_state == code(TrackingState::kAlign) || reset || (resumed && !aligned_);

  // 6. An accepted resume or reset answers the HOLD or FAULT shown, after the minimum time.
  if (resumed || reset) {
    const TrackingState answers = resumed ? TrackingState::kHold : TrackingState::kFault;
    if (r.previous_state != code(answers))
      fail(std::string(resumed ? "resume" : "reset") + " acted on outside " + to_string(answers));
    if (hold_id_ == 0 || !action.accepted || action.named_id != hold_id_)
      fail("an accepted " + std::string(resumed ? "resume" : "reset") + " named hold " +
           std::to_string(action.named_id) + ", the loop was in hold " + std::to_string(hold_id_));
    if (double(r.cycle - hold_since_) * period_s_ < kMinHoldBeforeResumeS - 1e-9)
      fail(std::string(resumed ? "a resume" : "a reset") + " acted on " +
           std::to_string(r.cycle - hold_since_) + " cycles into its " + (resumed ? "HOLD" : "FAULT"));
    needs_operator_ = false;
    if (resumed) step_approved_ = true;
    if (reset) aligned_ = false;  // the loop aligns again before it moves
  }

  // 1, 2. What the device was told, and what the journal says it was told.
  if (calls.non_finite) fail("a non-finite value reached the actuator");
  if (calls.commands_failed == 0 && sent != (calls.commands_accepted > 0))
    fail(sent ? "the journal records a command the actuator never accepted"
              : "the actuator accepted a command the journal does not record");
  if (sent && calls.commands_accepted > 0) {
    for (int i = 0; i < 6; ++i)
      if (!(std::abs(r.command[i] - calls.last_command[i]) <= 1e-9 * (1 + std::abs(r.command[i])))) {
        fail("the journal's command differs from the one sent");
        break;
      }
  }
  if (beam != calls.beam_permit) fail("the journal's beam permit differs from the device's");

  // 3. Limits on what was sent. The alignment's record sets the aligned target, with or without
  // a set-up move to send (one with nothing to move sends nothing).
  const bool setup_move = r.event == 1 + static_cast<int>(TrackingEvent::kAligned);
  if (setup_move) {
    aligned_ = true;
    aligned_target_ = calls.target_after;
  }
  if (calls.commands_accepted > 0) {
    const tracking::Vector6d& step = calls.last_command;
    if (!setup_move) {
      if (!step_approved_ && beyond_step_limit(limits_, step))
        fail("a step of " + mm_deg(translation_mm(step), angle_deg(step)) + " beyond the step limit");
      if (aligned_) {
        const tracking::Vector6d total = calls.target_after - aligned_target_;
        if (beyond(translation_mm(total), angle_deg(total), limits_.max_total_mm, limits_.max_total_deg))
          fail("a total of " + mm_deg(translation_mm(total), angle_deg(total)) +
               " from the aligned pose, beyond the total limit");
      } else {
        fail("a command before any alignment");
      }
    }
    step_approved_ = false;
  }

  // 4. The beam only in TRACK after APPLY, and only once the patient is in place.
  if (beam &&
      !(r.state == code(TrackingState::kTrack) && r.gate_decision == std::uint8_t(GateDecision::kApply)))
    fail("beam permit outside TRACK after APPLY");
  if (beam && calls.commands_accepted > 0 && beyond_step_limit(limits_, calls.last_command))
    fail("beam permit in the cycle of a " +
         mm_deg(translation_mm(calls.last_command), angle_deg(calls.last_command)) +
         " move beyond the step limit");
  if (beam && calls.have_readback && beyond_beam_tolerance(limits_, calls.travel_left))
    fail("beam permit while the actuator was still " +
         mm_deg(distance_mm(calls.travel_left), angle_deg(calls.travel_left)) + " from its target");
  const Eigen::Map<const tracking::Vector6d> offset(r.pose_delta);  // the registered patient, from the plan
  if (beam && beyond_beam_tolerance(limits_, offset))
    fail("beam permit with the registered patient " + mm_deg(distance_mm(offset), angle_deg(offset)) +
         " from the planned pose");

  // 5. No move and no beam between a HOLD or FAULT and the operator's answer.
  if (needs_operator_ && (sent || beam))
    fail("moved or armed the beam after a HOLD without an operator decision");

  // 7. Each injected fault in its safe state.
  if (injected.frame_fault && (sent || beam)) fail("a frame fault's cycle sent a command or kept the beam");
  if (injected.readback_fault && (sent || !held(r.state)))
    fail(std::string("a read-back fault's cycle ended in ") + to_string(TrackingState(r.state)) +
         (sent ? " and sent a command" : ""));
  if (injected.command_fault && !held(r.state))
    fail(std::string("a failed command's cycle ended in ") + to_string(TrackingState(r.state)));
  if (injected.stalled && r.overrun == 0) fail("a stalled cycle was not recorded as an overrun");
  if (overruns_in_a_row_ >= limits_.hold_after_overruns && (sent || beam))
    fail("sent or armed after " + std::to_string(overruns_in_a_row_) + " overruns in a row");
  if (r.gate_reason == std::uint8_t(GateReason::kJournalFailed)) journal_failed_ = true;
  if (journal_failed_ && (sent || beam)) fail("sent or armed after the journal failed");

  // 8. A failed surrogate holds the tracking it steers.
  const bool began_in_track = r.previous_state == code(TrackingState::kTrack);
  if (began_in_track && r.surrogate_fault != 0 && (sent || beam || !held(r.state)))
    fail(std::string("a failed surrogate's TRACK cycle ended in ") + to_string(TrackingState(r.state)) +
         (sent ? " and sent a command" : "") + (beam ? " with the beam on" : ""));
  if (began_in_track && injected.surrogate_reading && r.surrogate_fault == 0)
    fail(std::string("an injected ") + injected.what + " reading was not found in its TRACK cycle");

  // What the next cycle is judged against.
  overruns_in_a_row_ = r.overrun != 0 && !ran_in_align ? overruns_in_a_row_ + 1 : 0;
  if (held(r.state)) {
    needs_operator_ = true;
    if (r.hold_id != hold_id_) hold_since_ = r.cycle;
    hold_id_ = r.hold_id;
  } else {
    hold_id_ = 0;
  }
}

}  // namespace lftrack::chaos
