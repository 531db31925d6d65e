#pragma once
// The tracking state machine (DESIGN.md, "One cycle"):
//   IDLE -> ALIGN -> TRACK <-> HOLD -> FAULT
// ALIGN runs the cold registration once; TRACK applies gated corrections; HOLD stops motion and
// the beam until an operator resumes; FAULT is the safe stop (actuators held, beam off) that only
// an operator reset leaves, to IDLE. Every transition has a reason for the journal. The beam
// permit is on only in TRACK after an APPLY decision in the same cycle that does not withhold it
// (GateOutput::beam_allowed: not while the patient is still being moved into place).

#include <cstdint>

#include "lftrack/loop/safety_gate.hpp"

namespace lftrack::loop {

enum class TrackingState : std::uint8_t { kIdle = 0, kAlign = 1, kTrack = 2, kHold = 3, kFault = 4 };
const char* to_string(TrackingState state);

enum class TrackingEvent : std::uint8_t {
  kStart,           // operator: begin (IDLE -> ALIGN)
  kAligned,         // the cold registration succeeded and the actuator accepted its set-up move
  kAlignFailed,     // either did not (-> HOLD: the operator decides; a resume aligns again)
  kGate,            // a gate decision (see gate)
  kOperatorResume,  // HOLD -> TRACK (or ALIGN if never aligned)
  kOperatorStop,    // any -> IDLE, actuators held
  kOperatorReset,   // FAULT -> IDLE
  kDeviceFault,     // a device cannot be trusted any more (-> FAULT)
};
const char* to_string(TrackingEvent event);

struct StateTransition {
  TrackingState from = TrackingState::kIdle;
  TrackingState to = TrackingState::kIdle;
  bool changed() const { return from != to; }
  const char* reason = "";  // static text
};

class TrackingStateMachine {
 public:
  TrackingState state() const { return state_; }
  bool aligned() const { return aligned_; }
  // Applies an event (with the gate's output for kGate) and says what happened. Events that do
  // not apply in the current state leave it unchanged (reason says so).
  StateTransition on(TrackingEvent event, const GateOutput& gate = {});
  // True only in TRACK after an APPLY in this cycle that allows the beam.
  bool beam_permit() const { return beam_permit_; }

 private:
  TrackingState state_ = TrackingState::kIdle;
  bool aligned_ = false;
  bool beam_permit_ = false;
};

}  // namespace lftrack::loop
