#include "lftrack/drivers/recorded_actuator.hpp"

namespace lftrack::drivers {

Status RecordedActuator::open() {
  if (frames_ == nullptr || !frames_->sequence().has_actuator)
    return failed_precondition("recorded actuator: the sequence has no actuator.csv");
  target_.setZero();
  return {};
}

DeviceStatus RecordedActuator::command(const tracking::Vector6d& correction, Deadline) {
  if (!correction.allFinite()) return DeviceStatus::kFault;
  target_ += correction;
  return DeviceStatus::kOk;
}

DeviceStatus RecordedActuator::readback(ActuatorState* state, Deadline) {
  const SequencePair* pair = frames_->delivered();
  if (pair == nullptr || !pair->has_actuator) return DeviceStatus::kFault;
  for (int i = 0; i < 6; ++i) state->position(i) = pair->actuator_travel[i];
  state->target = target_;
  state->moving = false;
  state->fault = false;
  return DeviceStatus::kOk;
}

}  // namespace lftrack::drivers
