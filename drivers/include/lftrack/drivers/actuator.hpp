#pragma once
// What moves the patient: a couch (Modbus), a beam robot (CAN) or the simulator's virtual couch.
//
// A correction is a pose change of the patient in the room frame, as the 6-vector the optimizer
// uses (t [mm], omega [rad]) about the registration origin. The actuator's read-back is its
// total travel since it was zeroed, in the same terms.

#include "lftrack/drivers/device.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::drivers {

struct ActuatorState {
  tracking::Vector6d position = tracking::Vector6d::Zero();  // total travel (mm, rad)
  tracking::Vector6d target = tracking::Vector6d::Zero();    // the last command it accepted, as travel
  bool moving = false;
  bool fault = false;
};

class Actuator {
 public:
  virtual ~Actuator() = default;
  virtual Status open() = 0;
  // In the cycle: move by `correction` relative to the last commanded target.
  virtual DeviceStatus command(const tracking::Vector6d& correction, Deadline deadline) = 0;
  virtual DeviceStatus readback(ActuatorState* state, Deadline deadline) = 0;
  // Stop where it is and refuse motion until the next command after a resume.
  virtual void hold() = 0;
  // Every cycle, after the state machine: whether the beam may be on (a robot that carries the
  // beam gates it; a couch ignores it). Never blocks.
  virtual void set_beam_permit(bool permit) { (void)permit; }
  // True for a read-back tied to the frame pair just delivered (the recorded read-backs of an
  // archived sequence): the loop then reads back after the frames. Otherwise it reads back at
  // the cycle's start, the frames' exposure time, before waiting for them.
  virtual bool readback_follows_frames() const { return false; }
  // False for an actuator that moves no patient (the recorded read-backs of an archived
  // sequence): the loop still tells it its corrections, for its read-back's target, but records
  // none as sent.
  virtual bool moves_patient() const { return true; }
  virtual void close() = 0;
};

}  // namespace lftrack::drivers
