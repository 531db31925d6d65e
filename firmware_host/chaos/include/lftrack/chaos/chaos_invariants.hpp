#pragma once
// The chaos soak's invariants (chaos_soak.hpp), checked after every cycle from two witnesses
// that do not share code with the loop's decisions: the cycle's journal record, and what the
// actuator was really told (the soak's actuator wrapper logs every call as it passes):
//
//  1. Every value sent to the actuator is finite.
//  2. The journal says what the actuator was told: a command recorded if and only if one was
//     accepted by the device, with the same value; the beam permit recorded is the device's.
//  3. No command beyond the limits: each step within safety.max_step_* unless approved (the
//     set-up move of the ALIGN cycle; the first move after an accepted resume), and the total
//     travel from the aligned target within safety.max_total_*.
//  4. The beam permit only in TRACK, in a cycle whose gate decided APPLY, whose command (if
//     any) is within the step limit (not an approved larger move), whose registered patient (the
//     record's pose_delta) is within safety.beam_tolerance_* of the planned pose, and whose
//     read-back found the device within beam_tolerance_* of its target.
//  5. Nothing re-arms the beam or moves without a fresh operator decision: after a cycle that
//     ends in HOLD or FAULT, no command and no beam until a cycle with an accepted resume or
//     reset.
//  6. A resume is accepted only in HOLD (a reset only in FAULT) that has been shown for at
//     least kMinHoldBeforeResumeS, and names that HOLD's id.
//  7. Every injected fault reaches its catalogued safe state (docs/faults.md): a frame fault
//     sends nothing and keeps the beam off in its cycle; a read-back fault ends its cycle in
//     HOLD or FAULT with nothing sent; a failed command ends its cycle in HOLD or FAULT; a
//     stalled cycle is recorded as an overrun, and the cycle after three overruns in a row sends
//     nothing; once the loop reports the journal failed, nothing is sent and the beam stays off.
//  8. A breathing surrogate found failed (the record's surrogate fault: stopped, jumped, frozen,
//     not finite) in a cycle that began in TRACK ends it held (HOLD, or FAULT), nothing sent, the beam
//     off; an injected spike or NaN reading in such a cycle is found in it.
// The soak (chaos_soak.cpp) adds what needs the wall clock or the segment: half a second after
// the disk filled nothing is sent (whatever reason the gate gives first); a CAN fault holds
// within 50 cycles and 2 s; an exception leaves the actuator held and the beam off; each
// segment's journal holds one valid record per cycle, in order.

#include <cstdint>
#include <string>
#include <vector>

#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/tracking/pose.hpp"

namespace lftrack::chaos {

// The loop's vocabulary, which the soak speaks (the loop's types live in lftrack::loop).
using loop::GateDecision;
using loop::GateReason;
using loop::JournalRecord;
using loop::kMinHoldBeforeResumeS;
using loop::OperatorCommand;
using loop::OperatorPoll;
using loop::OperatorRefusal;
using loop::OperatorRequest;
using loop::OperatorView;
using loop::SafetyLimits;
using loop::TrackingEvent;
using loop::TrackingState;

// What the actuator was told in one cycle, as its wrapper saw the calls.
struct ActuatorCalls {
  int commands_accepted = 0;  // command() calls the device answered kOk
  int commands_failed = 0;    // command() calls that failed (timeout, fault, disconnect, throw)
  bool non_finite = false;    // a command() value was not finite
  tracking::Vector6d last_command = tracking::Vector6d::Zero();  // the last accepted command
  // The device's target after the cycle's calls, as read back or commanded (carried across
  // cycles): where the last accepted command took it, or the aligned target of an alignment with
  // nothing to move.
  tracking::Vector6d target_after = tracking::Vector6d::Zero();
  bool beam_permit = false;  // the device's beam permit after the cycle
  // The cycle's first read-back, the one at the frames' exposure, as the device answered it:
  // whether there was one, and its target less its position (the travel still to make).
  bool have_readback = false;
  tracking::Vector6d travel_left = tracking::Vector6d::Zero();
};

// What the soak injected into one cycle (and that met the loop).
struct CycleInjection {
  bool frame_fault = false;     // any frame fault but a throw
  bool readback_fault = false;  // a read-back fault that was answered to the loop
  bool command_fault = false;   // a command that failed
  bool stalled = false;         // the cycle was made to overrun
  bool surrogate_reading = false;  // a spiked or NaN surrogate reading was given to the cycle
  const char* what = "";        // the injected fault's name, or the device's own failure, for messages
};

// What the operator did in one cycle, as the soak's operator knows it.
struct OperatorAction {
  bool accepted = false;       // a resume or reset it sent was accepted into the poll
  std::uint32_t named_id = 0;  // the hold id that command named
};

class InvariantChecker {
 public:
  InvariantChecker(const SafetyLimits& limits, double period_s) : limits_(limits), period_s_(period_s) {}
  // One cycle, in order. Appends a line per violation to `violations`.
  void check(const JournalRecord& record, const ActuatorCalls& calls, const CycleInjection& injected,
             const OperatorAction& action, std::vector<std::string>* violations);
  // The journal reported failed (the gate's kJournalFailed) from this cycle on.
  bool journal_failed() const { return journal_failed_; }

 private:
  SafetyLimits limits_;
  double period_s_;
  bool aligned_ = false;
  tracking::Vector6d aligned_target_ = tracking::Vector6d::Zero();
  bool step_approved_ = false;    // an accepted resume approved the next move
  bool needs_operator_ = false;   // a HOLD or FAULT has not yet been answered
  std::uint32_t hold_id_ = 0;     // the HOLD or FAULT the last record ended in
  std::uint64_t hold_since_ = 0;  // the cycle it began in
  int overruns_in_a_row_ = 0;
  bool journal_failed_ = false;
};

}  // namespace lftrack::chaos
