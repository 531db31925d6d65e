// The chaos soak's invariant checker on hand-made cycles: each invariant broken once is reported,
// and the same cycles done right are not.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "lftrack/chaos/chaos_invariants.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/tracking_states.hpp"

namespace lftrack::session {

using loop::GateDecision;
using loop::GateReason;
using loop::JournalRecord;
using loop::OperatorCommand;
using loop::SafetyLimits;
using loop::TrackingEvent;
using loop::TrackingState;
namespace {

using chaos::ActuatorCalls;
using chaos::CycleInjection;
using chaos::InvariantChecker;
using chaos::OperatorAction;

constexpr double kPeriodS = 0.1;

std::uint8_t code(TrackingState s) {
  return static_cast<std::uint8_t>(s);
}

// One cycle as the checker sees it; defaults: tracking, nothing sent, beam off.
struct Cycle {
  JournalRecord record;
  ActuatorCalls calls;
  CycleInjection injected;
  OperatorAction action;
};

// A checker with the default limits (2 mm steps, 10 mm in all) and the cycles to feed it.
struct Harness {
  Cycle tracking_cycle(std::uint64_t index) {
    Cycle c;
    c.record.cycle = index;
    c.record.previous_state = code(TrackingState::kTrack);
    c.record.state = code(TrackingState::kTrack);
    c.record.gate_decision = std::uint8_t(GateDecision::kApply);
    return c;
  }
  // A tracking cycle that sends `step` (mm along x) with the beam on.
  Cycle applied(std::uint64_t index, double step_mm) {
    Cycle c = tracking_cycle(index);
    c.record.command_sent = 1;
    c.record.command[0] = step_mm;
    c.record.beam_permit = 1;
    c.calls.commands_accepted = 1;
    c.calls.last_command = tracking::Vector6d::Zero();
    c.calls.last_command[0] = step_mm;
    c.calls.beam_permit = true;
    target_ += c.calls.last_command;
    c.calls.target_after = target_;
    return c;
  }
  // The ALIGN cycle's set-up move to `x_mm` (the beam off: the loop aligns without it).
  Cycle aligned(double x_mm) {
    Cycle c = applied(0, x_mm);
    c.record.previous_state = code(TrackingState::kAlign);
    c.record.event = 1 + static_cast<int>(TrackingEvent::kAligned);
    c.record.beam_permit = 0;
    c.calls.beam_permit = false;
    return c;
  }
  Cycle held(std::uint64_t index, std::uint32_t hold_id, TrackingState state = TrackingState::kHold) {
    Cycle c = tracking_cycle(index);
    c.record.state = code(state);
    c.record.previous_state = code(state);
    c.record.gate_decision = std::uint8_t(GateDecision::kHold);
    c.record.hold_id = hold_id;
    return c;
  }
  std::vector<std::string> check(const Cycle& c) {
    std::vector<std::string> v;
    checker_.check(c.record, c.calls, c.injected, c.action, &v);
    return v;
  }
  static bool mentions(const std::vector<std::string>& v, const std::string& what) {
    for (const std::string& s : v)
      if (s.find(what) != std::string::npos) return true;
    return false;
  }

  SafetyLimits limits_;
  InvariantChecker checker_{limits_, kPeriodS};
  tracking::Vector6d target_ = tracking::Vector6d::Zero();
};

TEST(ChaosInvariants, AnAlignmentAndStepsWithinTheLimitsPass) {
  Harness h;
  EXPECT_TRUE(h.check(h.aligned(6.0)).empty()) << "the set-up move is approved";
  for (std::uint64_t k = 1; k < 5; ++k) EXPECT_TRUE(h.check(h.applied(k, 1.5)).empty()) << k;
}

TEST(ChaosInvariants, ANonFiniteValueAtTheActuatorIsReported) {
  Harness h;
  ASSERT_TRUE(h.check(h.aligned(1)).empty());
  Cycle c = h.applied(1, 0.5);
  c.calls.non_finite = true;
  EXPECT_TRUE(h.mentions(h.check(c), "non-finite"));
}

TEST(ChaosInvariants, AStepOrATotalBeyondItsLimitIsReported) {
  Harness h;
  ASSERT_TRUE(h.check(h.aligned(1)).empty());
  EXPECT_TRUE(h.mentions(h.check(h.applied(1, 2.5)), "step limit"));
  Harness fresh;
  ASSERT_TRUE(fresh.check(fresh.aligned(0)).empty());
  for (std::uint64_t k = 1; k <= 5; ++k) ASSERT_TRUE(fresh.check(fresh.applied(k, 2.0)).empty()) << k;
  EXPECT_TRUE(h.mentions(fresh.check(fresh.applied(6, 1.0)), "total limit")) << "11 mm from the aligned pose";
}

TEST(ChaosInvariants, TheJournalMustSayWhatTheActuatorWasTold) {
  Harness h;
  ASSERT_TRUE(h.check(h.aligned(1)).empty());
  Cycle unrecorded = h.applied(1, 0.5);
  unrecorded.record.command_sent = 0;
  EXPECT_TRUE(h.mentions(h.check(unrecorded), "does not record"));
  Cycle different = h.applied(2, 0.5);
  different.record.command[0] = 0.4;
  EXPECT_TRUE(h.mentions(h.check(different), "differs"));
  Cycle beam = h.tracking_cycle(3);
  beam.calls.beam_permit = true;  // the device's permit on, the journal's off
  EXPECT_TRUE(h.mentions(h.check(beam), "beam permit differs"));
}

TEST(ChaosInvariants, TheBeamOnlyInTrackAfterApply) {
  Harness h;
  Cycle skip = h.tracking_cycle(1);
  skip.record.gate_decision = std::uint8_t(GateDecision::kSkip);
  skip.record.beam_permit = 1;
  skip.calls.beam_permit = true;
  EXPECT_TRUE(h.mentions(h.check(skip), "outside TRACK after APPLY"));
}

// The beam waits while the patient is moved into place: not in the cycle of an approved move
// beyond the step limit, and not while the read-back found the actuator more than one step limit
// from its target.
TEST(ChaosInvariants, TheBeamWaitsUntilThePatientIsInPlace) {
  Harness h;
  ASSERT_TRUE(h.check(h.aligned(1)).empty());
  ASSERT_TRUE(h.check(h.held(1, 417263)).empty());
  Cycle resumed = h.applied(12, 3.0);  // approved, and the beam on with it
  resumed.record.previous_state = code(TrackingState::kHold);
  resumed.record.operator_command = 1 + static_cast<int>(OperatorCommand::kResume);
  resumed.action = {true, 417263};
  EXPECT_TRUE(h.mentions(h.check(resumed), "move beyond the step limit"));

  Harness t;
  ASSERT_TRUE(t.check(t.aligned(6)).empty());
  Cycle travelling = t.applied(1, 0.5);
  travelling.calls.have_readback = true;
  travelling.calls.travel_left[1] = -4.0;  // the set-up move still under way
  EXPECT_TRUE(t.mentions(t.check(travelling), "still 4.000000 mm / 0.000000 deg from its target"));
  Cycle turning = t.applied(2, 0.5);
  turning.calls.have_readback = true;
  turning.calls.travel_left[5] = tracking::deg_to_rad(2.5);
  EXPECT_TRUE(t.mentions(t.check(turning), "from its target"));
  Cycle diagonal = t.applied(3, 0.5);  // within a step on each axis, 3.3 mm from the plan
  diagonal.record.pose_delta[0] = diagonal.record.pose_delta[2] = 1.9;
  diagonal.record.pose_delta[1] = -1.9;
  EXPECT_TRUE(t.mentions(t.check(diagonal), "registered patient 3.290897 mm / 0.000000 deg from the planned pose"));
  Cycle rotated = t.applied(4, 0.5);
  rotated.record.pose_delta[4] = tracking::deg_to_rad(2.2);
  EXPECT_TRUE(t.mentions(t.check(rotated), "from the planned pose"));
  Cycle tracking_cycle = t.applied(5, 1.5);
  tracking_cycle.calls.have_readback = true;
  tracking_cycle.calls.travel_left[1] = -1.9;  // a step behind the patient
  tracking_cycle.record.pose_delta[1] = 0.4;
  EXPECT_TRUE(t.check(tracking_cycle).empty()) << "tracking, in place";
  Cycle no_beam = t.applied(6, 0.5);
  no_beam.record.beam_permit = 0;
  no_beam.calls.beam_permit = false;
  no_beam.calls.have_readback = true;
  no_beam.calls.travel_left[0] = 8.0;
  no_beam.record.pose_delta[0] = 8.0;
  EXPECT_TRUE(t.check(no_beam).empty()) << "out of place with the beam off is no violation";
}

TEST(ChaosInvariants, NothingMovesAfterAHoldUntilAnAcceptedResumeOfThatHoldAfterASecond) {
  Harness h;
  ASSERT_TRUE(h.check(h.aligned(1)).empty());
  ASSERT_TRUE(h.check(h.held(1, 417263)).empty());
  Cycle silently_back = h.applied(2, 0.5);  // TRACK again, no operator
  EXPECT_TRUE(h.mentions(h.check(silently_back), "without an operator decision"));

  Harness t;
  ASSERT_TRUE(t.check(t.aligned(1)).empty());
  ASSERT_TRUE(t.check(t.held(1, 417263)).empty());
  Cycle too_soon = t.applied(5, 3.0);  // 0.4 s into the HOLD, a 3 mm approved move
  too_soon.record.previous_state = code(TrackingState::kHold);
  too_soon.record.operator_command = 1 + static_cast<int>(OperatorCommand::kResume);
  too_soon.action = {true, 417263};
  EXPECT_TRUE(h.mentions(t.check(too_soon), "cycles into its HOLD"));

  Harness u;
  ASSERT_TRUE(u.check(u.aligned(1)).empty());
  ASSERT_TRUE(u.check(u.held(1, 417263)).empty());
  Cycle other_id = u.applied(12, 0.5);
  other_id.record.previous_state = code(TrackingState::kHold);
  other_id.record.operator_command = 1 + static_cast<int>(OperatorCommand::kResume);
  other_id.action = {true, 417264};
  EXPECT_TRUE(h.mentions(u.check(other_id), "named hold 417264"));

  Harness ok;
  ASSERT_TRUE(ok.check(ok.aligned(1)).empty());
  ASSERT_TRUE(ok.check(ok.held(1, 417263)).empty());
  Cycle resumed = ok.applied(12, 3.0);  // the resumed first move is approved beyond the step limit
  resumed.record.previous_state = code(TrackingState::kHold);
  resumed.record.operator_command = 1 + static_cast<int>(OperatorCommand::kResume);
  resumed.action = {true, 417263};
  resumed.record.beam_permit = 0;  // and makes it without the beam
  resumed.calls.beam_permit = false;
  EXPECT_TRUE(ok.check(resumed).empty());
  EXPECT_TRUE(h.mentions(ok.check(ok.applied(13, 3.0)), "step limit")) << "only the first move is approved";
}

TEST(ChaosInvariants, EachInjectedFaultMustReachItsSafeState) {
  Harness h;
  ASSERT_TRUE(h.check(h.aligned(1)).empty());
  Cycle frame = h.applied(1, 0.5);
  frame.injected.frame_fault = true;
  frame.injected.what = "frame_torn";
  const auto v = h.check(frame);
  EXPECT_TRUE(h.mentions(v, "frame fault")) << "a torn frame's cycle moved";
  EXPECT_TRUE(h.mentions(v, "frame_torn")) << "the message names the fault";

  Cycle readback = h.tracking_cycle(2);
  readback.injected.readback_fault = true;
  EXPECT_TRUE(h.mentions(h.check(readback), "read-back fault's cycle ended in TRACK"));

  Cycle command = h.tracking_cycle(3);
  command.calls.commands_failed = 1;
  command.injected.command_fault = true;
  EXPECT_TRUE(h.mentions(h.check(command), "failed command's cycle ended in TRACK"));

  Cycle stalled = h.tracking_cycle(4);
  stalled.injected.stalled = true;
  EXPECT_TRUE(h.mentions(h.check(stalled), "not recorded as an overrun"));
}

// A command with no alignment before it is reported; an alignment with nothing to move (its
// record the alignment's, no command) counts as one; after an accepted reset the loop must
// align again before it moves.
TEST(ChaosInvariants, EveryMoveNeedsAnAlignmentSinceTheLastReset) {
  Harness never;
  EXPECT_TRUE(never.mentions(never.check(never.applied(0, 0.5)), "before any alignment"));

  Harness still;
  Cycle nothing_to_move = still.tracking_cycle(0);
  nothing_to_move.record.previous_state = code(TrackingState::kAlign);
  nothing_to_move.record.event = 1 + static_cast<int>(TrackingEvent::kAligned);
  nothing_to_move.record.gate_decision = std::uint8_t(GateDecision::kApply);
  ASSERT_TRUE(still.check(nothing_to_move).empty());
  EXPECT_TRUE(still.check(still.applied(1, 0.5)).empty()) << "aligned, with nothing to move";

  Harness h;
  ASSERT_TRUE(h.check(h.aligned(1)).empty());
  ASSERT_TRUE(h.check(h.held(1, 417263, TrackingState::kFault)).empty());
  Cycle reset = h.tracking_cycle(12);  // the reset's cycle ends in ALIGN, a pair skipped
  reset.record.previous_state = code(TrackingState::kFault);
  reset.record.state = code(TrackingState::kAlign);
  reset.record.gate_decision = std::uint8_t(GateDecision::kSkip);
  reset.record.operator_command = 1 + static_cast<int>(OperatorCommand::kReset);
  reset.action = {true, 417263};
  ASSERT_TRUE(h.check(reset).empty());
  EXPECT_TRUE(h.mentions(h.check(h.applied(13, 0.5)), "before any alignment")) << "no alignment since the reset";
}

// An overrun in a cycle that ran in ALIGN (a cold registration) does not count towards the
// overruns in a row, also when a resume took the loop there from a HOLD before any alignment.
TEST(ChaosInvariants, AnAlignmentsOverrunIsNotCountedInARow) {
  Harness h;
  for (std::uint64_t k = 0; k < 2; ++k) {  // the alignment failed: two HOLD cycles that overran
    Cycle c = h.held(k, 654321);
    c.record.overrun = 1;
    ASSERT_TRUE(h.check(c).empty());
  }
  Cycle realign = h.applied(12, 3.0);  // the resume aligns again: the set-up move, overrunning
  realign.record.previous_state = code(TrackingState::kHold);
  realign.record.operator_command = 1 + static_cast<int>(OperatorCommand::kResume);
  realign.record.event = 1 + static_cast<int>(TrackingEvent::kAligned);
  realign.record.beam_permit = 0;
  realign.calls.beam_permit = false;
  realign.record.overrun = 1;
  realign.action = {true, 654321};
  ASSERT_TRUE(h.check(realign).empty());
  EXPECT_TRUE(h.check(h.applied(13, 0.5)).empty()) << "the alignment's overrun ended the run of overruns";
}

TEST(ChaosInvariants, ThreeOverrunsInARowThenNothingIsSent) {
  Harness h;
  ASSERT_TRUE(h.check(h.aligned(1)).empty());
  for (std::uint64_t k = 1; k <= 3; ++k) {
    Cycle c = h.tracking_cycle(k);
    c.record.overrun = 1;
    ASSERT_TRUE(h.check(c).empty());
  }
  EXPECT_TRUE(h.mentions(h.check(h.applied(4, 0.5)), "overruns in a row"));
}

TEST(ChaosInvariants, AfterTheJournalFailedNothingIsSent) {
  Harness h;
  ASSERT_TRUE(h.check(h.aligned(1)).empty());
  Cycle failed = h.held(1, 123456);
  failed.record.gate_reason = std::uint8_t(GateReason::kJournalFailed);
  ASSERT_TRUE(h.check(failed).empty());
  EXPECT_TRUE(h.checker_.journal_failed());
  Cycle resumed = h.applied(15, 0.5);
  resumed.record.previous_state = code(TrackingState::kHold);
  resumed.record.operator_command = 1 + static_cast<int>(OperatorCommand::kResume);
  resumed.action = {true, 123456};
  EXPECT_TRUE(h.mentions(h.check(resumed), "after the journal failed")) << "even a resumed loop";
}

}  // namespace
}  // namespace lftrack::session
