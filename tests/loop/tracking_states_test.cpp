#include "lftrack/loop/tracking_states.hpp"

#include <gtest/gtest.h>

namespace lftrack::loop {
namespace {

GateOutput gate(GateDecision d, GateReason r = GateReason::kOk) {
  GateOutput g;
  g.decision = d;
  g.reason = r;
  return g;
}

TEST(TrackingStates, NormalLifeCycle) {
  TrackingStateMachine m;
  EXPECT_EQ(m.state(), TrackingState::kIdle);
  auto t = m.on(TrackingEvent::kStart);
  EXPECT_TRUE(t.changed());
  EXPECT_EQ(t.to, TrackingState::kAlign);
  t = m.on(TrackingEvent::kAligned);
  EXPECT_EQ(t.to, TrackingState::kTrack);
  EXPECT_FALSE(m.beam_permit());
  t = m.on(TrackingEvent::kGate, gate(GateDecision::kApply));
  EXPECT_FALSE(t.changed());
  EXPECT_TRUE(m.beam_permit());
  t = m.on(TrackingEvent::kGate, gate(GateDecision::kSkip, GateReason::kStaleFrame));
  EXPECT_EQ(m.state(), TrackingState::kTrack);
  EXPECT_FALSE(m.beam_permit()) << "no beam without a fresh valid result";
  EXPECT_STREQ(t.reason, "stale frame");
}

// An APPLY that withholds the beam (the patient still being moved into place) tracks on, with
// the beam off; the next APPLY that allows it turns it on.
TEST(TrackingStates, AnApplyThatWithholdsTheBeamTracksWithTheBeamOff) {
  TrackingStateMachine m;
  m.on(TrackingEvent::kStart);
  m.on(TrackingEvent::kAligned);
  for (BeamWithheld w : {BeamWithheld::kApprovedStep, BeamWithheld::kActuatorTravelling}) {
    GateOutput g = gate(GateDecision::kApply);
    g.beam_withheld = w;
    const StateTransition t = m.on(TrackingEvent::kGate, g);
    EXPECT_FALSE(t.changed());
    EXPECT_EQ(m.state(), TrackingState::kTrack);
    EXPECT_FALSE(m.beam_permit()) << to_string(w);
    EXPECT_STREQ(t.reason, "applied, beam withheld");
  }
  m.on(TrackingEvent::kGate, gate(GateDecision::kApply));
  EXPECT_TRUE(m.beam_permit());
}

TEST(TrackingStates, HoldNeedsTheOperator) {
  TrackingStateMachine m;
  m.on(TrackingEvent::kStart);
  m.on(TrackingEvent::kAligned);
  auto t = m.on(TrackingEvent::kGate, gate(GateDecision::kHold, GateReason::kStepTooLarge));
  EXPECT_EQ(t.to, TrackingState::kHold);
  EXPECT_STREQ(t.reason, "correction step above limit");
  EXPECT_FALSE(m.beam_permit());
  // Good results do not leave HOLD by themselves.
  for (int i = 0; i < 5; ++i) {
    t = m.on(TrackingEvent::kGate, gate(GateDecision::kApply));
    EXPECT_EQ(m.state(), TrackingState::kHold);
    EXPECT_FALSE(m.beam_permit());
  }
  t = m.on(TrackingEvent::kOperatorResume);
  EXPECT_EQ(t.to, TrackingState::kTrack);
  m.on(TrackingEvent::kGate, gate(GateDecision::kApply));
  EXPECT_TRUE(m.beam_permit());
}

TEST(TrackingStates, FailedAlignmentHoldsAndResumeRealigns) {
  TrackingStateMachine m;
  m.on(TrackingEvent::kStart);
  EXPECT_EQ(m.on(TrackingEvent::kAlignFailed).to, TrackingState::kHold);
  EXPECT_EQ(m.on(TrackingEvent::kOperatorResume).to, TrackingState::kAlign);
}

// The gate stops (its failures in a row reached fault_after_failures) in ALIGN as in TRACK.
TEST(TrackingStates, AFailedAlignmentTheGateStopsIsAFault) {
  TrackingStateMachine m;
  m.on(TrackingEvent::kStart);
  const StateTransition t = m.on(TrackingEvent::kAlignFailed, gate(GateDecision::kStop, GateReason::kActuatorFault));
  EXPECT_EQ(t.to, TrackingState::kFault);
  EXPECT_STREQ(t.reason, "actuator read-back failed");
  EXPECT_FALSE(m.beam_permit());
  EXPECT_EQ(m.on(TrackingEvent::kOperatorResume).to, TrackingState::kFault) << "only a reset leaves FAULT";
}

TEST(TrackingStates, StopAndDeviceFaultsEndInFaultUntilReset) {
  for (TrackingEvent e : {TrackingEvent::kGate, TrackingEvent::kDeviceFault}) {
    TrackingStateMachine m;
    m.on(TrackingEvent::kStart);
    m.on(TrackingEvent::kAligned);
    m.on(e, gate(GateDecision::kStop, GateReason::kNoResult));
    EXPECT_EQ(m.state(), TrackingState::kFault);
    for (TrackingEvent any : {TrackingEvent::kStart, TrackingEvent::kAligned, TrackingEvent::kOperatorResume,
                              TrackingEvent::kOperatorStop}) {
      m.on(any, gate(GateDecision::kApply));
      EXPECT_EQ(m.state(), TrackingState::kFault) << to_string(any);
      EXPECT_FALSE(m.beam_permit());
    }
    EXPECT_EQ(m.on(TrackingEvent::kOperatorReset).to, TrackingState::kIdle);
    EXPECT_FALSE(m.aligned());
  }
  TrackingStateMachine m;
  m.on(TrackingEvent::kStart);
  m.on(TrackingEvent::kAligned);
  m.on(TrackingEvent::kGate, gate(GateDecision::kHold));
  EXPECT_EQ(m.on(TrackingEvent::kGate, gate(GateDecision::kStop)).to, TrackingState::kFault);
}

TEST(TrackingStates, OperatorStopReturnsToIdle) {
  TrackingStateMachine m;
  m.on(TrackingEvent::kStart);
  m.on(TrackingEvent::kAligned);
  EXPECT_EQ(m.on(TrackingEvent::kOperatorStop).to, TrackingState::kIdle);
  EXPECT_FALSE(m.aligned());
  EXPECT_FALSE(m.on(TrackingEvent::kGate, gate(GateDecision::kApply)).changed());
  EXPECT_FALSE(m.beam_permit());
}

}  // namespace
}  // namespace lftrack::loop
