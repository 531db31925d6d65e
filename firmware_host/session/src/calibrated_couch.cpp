#include "lftrack/session/calibrated_couch.hpp"

#include "lftrack/calib/couch_calibration.hpp"

namespace lftrack::session {

using tracking::Vector6d;

Vector6d CalibratedCouch::couch_move_for_correction(const Vector6d& correction) const {
  const tracking::Pose room_motion = tracking::apply_delta(
      tracking::Pose::Identity(), tracking::PoseDelta::from_vector(correction), origin_room_mm_);
  return calib::couch_move_for(T_room_from_couch_, room_motion);
}

Vector6d CalibratedCouch::correction_for_couch_position(const Vector6d& q) const {
  const Eigen::Isometry3d room_motion = calib::room_motion_of_couch(T_room_from_couch_, q);
  return tracking::delta_between(tracking::Pose::Identity(), room_motion, origin_room_mm_).as_vector();
}

// The loop's corrections add up as room-frame vectors, and the couch's moves add up along its
// own axes; the conversion between them is not linear (rotations about an off-axis centre). So
// the couch is sent the difference between the couch targets of the new and the old room target,
// never the conversion of the step alone: converting each step on its own drifted the couch's
// target away from the loop's by a second-order error that grew with travel, until the read-back
// check held a correct loop (about 0.5 mm after 118 cycles of breathing through a couch mounted
// 1 degree off with its centre 200 mm away).
drivers::DeviceStatus CalibratedCouch::command(const Vector6d& correction, drivers::Deadline deadline) {
  const Vector6d room_target = correction_for_couch_position(couch_target_) + correction;
  const Vector6d couch_target = couch_move_for_correction(room_target);
  const Vector6d move = couch_target - couch_target_;
  if (!move.allFinite()) return drivers::DeviceStatus::kRefused;
  const drivers::DeviceStatus sent = couch_->command(move, deadline);
  // A move that may have been taken (timeout) leaves the target unknown: the next read-back
  // says where it is; until then the last known target stands.
  if (sent == drivers::DeviceStatus::kOk) couch_target_ += move;
  return sent;
}

drivers::DeviceStatus CalibratedCouch::readback(drivers::ActuatorState* state, drivers::Deadline deadline) {
  const drivers::DeviceStatus s = couch_->readback(state, deadline);
  if (s == drivers::DeviceStatus::kOk) {
    couch_target_ = state->target;
    state->position = correction_for_couch_position(state->position);
    state->target = correction_for_couch_position(state->target);
  }
  return s;
}

}  // namespace lftrack::session
