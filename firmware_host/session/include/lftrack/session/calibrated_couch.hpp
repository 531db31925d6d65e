#pragma once
// The couch as the loop sees it once calibrated (issue 8): the loop's corrections are room-frame
// deltas about the registration origin c (actuator.hpp); the couch moves along its own axes
// about its own rotation centre. This adaptor converts each correction through the couch
// calibration X = T_room_from_couch (calib/couch_calibration.hpp) into the couch move that
// produces it, and converts read-backs back into room terms. Without a calibration the loop
// assumes X = Translation(c), for which both conversions are the identity.
//
// Targets, not steps, are converted: the couch's target (its own axes, from the last read-back
// and the moves sent since) is kept, and a correction moves it to the couch target of the room
// target it implies, so the read-back target in room terms is the sum of the corrections sent.
//
// Cycle-safe: no allocation, no lock; a non-finite conversion is refused (kRefused: nothing sent).

#include <Eigen/Geometry>

#include "lftrack/drivers/actuator.hpp"

namespace lftrack::session {

class CalibratedCouch final : public drivers::Actuator {
 public:
  CalibratedCouch(drivers::Actuator* couch, const Eigen::Isometry3d& T_room_from_couch,
                  const Eigen::Vector3d& origin_room_mm)
      : couch_(couch), T_room_from_couch_(T_room_from_couch), origin_room_mm_(origin_room_mm) {}

  Status open() override { return couch_->open(); }
  drivers::DeviceStatus command(const tracking::Vector6d& correction, drivers::Deadline deadline) override;
  drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline deadline) override;
  void hold() override { couch_->hold(); }
  void set_beam_permit(bool permit) override { couch_->set_beam_permit(permit); }
  bool moves_patient() const override { return couch_->moves_patient(); }
  void close() override { couch_->close(); }

  // The conversions, for tests and reports.
  tracking::Vector6d couch_move_for_correction(const tracking::Vector6d& correction_room) const;
  tracking::Vector6d correction_for_couch_position(const tracking::Vector6d& couch_position) const;

 private:
  drivers::Actuator* couch_;
  Eigen::Isometry3d T_room_from_couch_;
  Eigen::Vector3d origin_room_mm_;
  tracking::Vector6d couch_target_ =
      tracking::Vector6d::Zero();  // couch axes: last read-back plus moves since
};

}  // namespace lftrack::session
