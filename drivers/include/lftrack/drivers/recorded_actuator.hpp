#pragma once
// The couch of a replayed sequence, as it was recorded (the sequence's actuator.csv).
//
// A recorded sequence shows the patient after the corrections made while recording; the loop
// can only tell the patient's own motion from those corrections by the couch's read-back. This
// actuator gives the loop that read-back: readback() returns the travel recorded for the pair
// the replay source delivered last. Commands are accepted and reported (the read-back's target
// follows them, so the loop's read-back check holds) but move nothing: the frames are fixed, and
// the loop records no command as sent (moves_patient).

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/drivers/replay_frame_source.hpp"

namespace lftrack::drivers {

class RecordedActuator final : public Actuator {
 public:
  // `frames` must outlive this actuator.
  explicit RecordedActuator(const ReplayFrameSource* frames) : frames_(frames) {}
  Status open() override;
  DeviceStatus command(const tracking::Vector6d& correction, Deadline deadline) override;
  // kFault when the delivered pair has no recorded read-back.
  DeviceStatus readback(ActuatorState* state, Deadline deadline) override;
  void hold() override {}
  void close() override {}
  bool readback_follows_frames() const override { return true; }
  bool moves_patient() const override { return false; }

 private:
  const ReplayFrameSource* frames_;
  tracking::Vector6d target_ = tracking::Vector6d::Zero();
};

}  // namespace lftrack::drivers
