#include "lftrack/host/calibrated_couch.hpp"

#include "lftrack/calib/couch_calibration.hpp"

namespace lftrack::host {

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

drivers::DeviceStatus CalibratedCouch::command(const Vector6d& correction, drivers::Deadline deadline) {
  const Vector6d move = couch_move_for_correction(correction);
  if (!move.allFinite()) return drivers::DeviceStatus::kRefused;
  return couch_->command(move, deadline);
}

drivers::DeviceStatus CalibratedCouch::readback(drivers::ActuatorState* state, drivers::Deadline deadline) {
  const drivers::DeviceStatus s = couch_->readback(state, deadline);
  if (s == drivers::DeviceStatus::kOk) {
    state->position = correction_for_couch_position(state->position);
    state->target = correction_for_couch_position(state->target);
  }
  return s;
}

}  // namespace lftrack::host
