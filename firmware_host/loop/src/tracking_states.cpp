#include "lftrack/loop/tracking_states.hpp"

namespace lftrack::loop {

const char* to_string(TrackingState s) {
  switch (s) {
    case TrackingState::kIdle:
      return "IDLE";
    case TrackingState::kAlign:
      return "ALIGN";
    case TrackingState::kTrack:
      return "TRACK";
    case TrackingState::kHold:
      return "HOLD";
    case TrackingState::kFault:
      return "FAULT";
  }
  return "?";
}

const char* to_string(TrackingEvent e) {
  switch (e) {
    case TrackingEvent::kStart:
      return "start";
    case TrackingEvent::kAligned:
      return "aligned";
    case TrackingEvent::kAlignFailed:
      return "alignment failed";
    case TrackingEvent::kGate:
      return "gate";
    case TrackingEvent::kOperatorResume:
      return "operator resume";
    case TrackingEvent::kOperatorStop:
      return "operator stop";
    case TrackingEvent::kOperatorReset:
      return "operator reset";
    case TrackingEvent::kDeviceFault:
      return "device fault";
  }
  return "?";
}

StateTransition TrackingStateMachine::on(TrackingEvent event, const GateOutput& gate) {
  StateTransition t;
  t.from = state_;
  beam_permit_ = false;
  auto go = [&](TrackingState to, const char* reason) {
    state_ = to;
    t.to = to;
    t.reason = reason;
    return t;
  };
  t.to = state_;
  t.reason = "event does not apply in this state";
  if (event == TrackingEvent::kOperatorStop) {
    if (state_ == TrackingState::kFault) return t;  // only a reset leaves FAULT
    aligned_ = false;
    return go(TrackingState::kIdle, "operator stop");
  }
  if (event == TrackingEvent::kDeviceFault) {
    return state_ == TrackingState::kIdle ? t : go(TrackingState::kFault, "device fault");
  }
  switch (state_) {
    case TrackingState::kIdle:
      if (event == TrackingEvent::kStart) return go(TrackingState::kAlign, "operator start");
      return t;
    case TrackingState::kAlign:
      if (event == TrackingEvent::kAligned) {
        aligned_ = true;
        return go(TrackingState::kTrack, "aligned");
      }
      // A failed alignment holds for the operator, or stops where the gate says so (its failures
      // in a row reached fault_after_failures): the same gate decision in TRACK stops too.
      if (event == TrackingEvent::kAlignFailed)
        return gate.decision == GateDecision::kStop ? go(TrackingState::kFault, to_string(gate.reason))
                                                    : go(TrackingState::kHold, "alignment failed");
      return t;
    case TrackingState::kTrack:
      if (event != TrackingEvent::kGate) return t;
      switch (gate.decision) {
        case GateDecision::kApply:
          beam_permit_ = gate.beam_allowed();
          t.reason = beam_permit_ ? "applied" : "applied, beam withheld";
          return t;
        case GateDecision::kSkip:
          t.reason = to_string(gate.reason);
          return t;
        case GateDecision::kHold:
          return go(TrackingState::kHold, to_string(gate.reason));
        case GateDecision::kStop:
          return go(TrackingState::kFault, to_string(gate.reason));
      }
      return t;
    case TrackingState::kHold:
      if (event == TrackingEvent::kOperatorResume)
        return aligned_ ? go(TrackingState::kTrack, "operator resume") : go(TrackingState::kAlign, "operator resume");
      if (event == TrackingEvent::kGate && gate.decision == GateDecision::kStop)
        return go(TrackingState::kFault, to_string(gate.reason));
      if (event == TrackingEvent::kGate) t.reason = "held: waiting for the operator";
      return t;
    case TrackingState::kFault:
      if (event == TrackingEvent::kOperatorReset) {
        aligned_ = false;
        return go(TrackingState::kIdle, "operator reset");
      }
      return t;
  }
  return t;
}

}  // namespace lftrack::loop
