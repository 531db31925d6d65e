#include "lftrack/sim/simulated_room.hpp"

#include <chrono>

#include "lftrack/calib/couch_calibration.hpp"

namespace lftrack::sim {

using tracking::Pose;
using tracking::PoseDelta;

SimulatedRoom::SimulatedRoom(const SimulatedRoomSpec& spec) : spec_(spec), couch_(spec.couch) {}

double SimulatedRoom::time_s() const {
  std::lock_guard lock(mutex_);
  return couch_.time_s();
}

double SimulatedRoom::time_s_at(std::int64_t t_ns) const {
  std::lock_guard lock(mutex_);
  return started_ ? 1e-9 * static_cast<double>(t_ns - epoch_ns_) : 0.0;
}

tracking::Vector6d SimulatedRoom::couch_position() const {
  std::lock_guard lock(mutex_);
  return couch_position_locked();
}

tracking::Vector6d SimulatedRoom::couch_position_locked() const {
  if (!spec_.couch_link) return couch_.position();
  RoomLinkSample sample;
  return spec_.couch_link->read(&sample) ? sample.couch_position : tracking::Vector6d::Zero();
}

std::int64_t SimulatedRoom::epoch_ns() const {
  std::lock_guard lock(mutex_);
  return started_ ? epoch_ns_ : -1;
}

void SimulatedRoom::advance_to_ns(std::int64_t t_ns) {
  std::lock_guard lock(mutex_);
  advance_locked(t_ns);
}

void SimulatedRoom::advance_locked(std::int64_t t_ns) {
  if (!started_) {
    started_ = true;
    epoch_ns_ = t_ns;
  }
  couch_.advance_to(1e-9 * static_cast<double>(t_ns - epoch_ns_));
}

void SimulatedRoom::advance_for_command(drivers::Deadline deadline) {
  std::lock_guard lock(mutex_);
  advance_for_command_locked(deadline);
}

void SimulatedRoom::advance_for_command_locked(drivers::Deadline deadline) {
  const std::int64_t deadline_ns =
      std::chrono::duration_cast<std::chrono::nanoseconds>(deadline.time_since_epoch()).count();
  if (started_ && deadline_ns > epoch_ns_) advance_locked(deadline_ns);
}

Pose SimulatedRoom::patient_T_room_from_ct() const {
  std::lock_guard lock(mutex_);
  return patient_locked();
}

Pose SimulatedRoom::true_T_room_from_ct() const {
  std::lock_guard lock(mutex_);
  return true_locked();
}

Pose SimulatedRoom::patient_locked() const {
  const Pose set_up = tracking::apply_delta(spec_.nominal_T_room_from_ct,
                                            PoseDelta::from_vector(spec_.setup_error), spec_.origin_room_mm);
  return tracking::apply_delta(set_up, PoseDelta::from_vector(patient_offset(spec_.motion, couch_.time_s())),
                               spec_.origin_room_mm);
}

Eigen::Isometry3d SimulatedRoom::T_room_from_couch() const {
  if (spec_.couch_T_room_from_couch) return *spec_.couch_T_room_from_couch;
  Eigen::Isometry3d ideal = Eigen::Isometry3d::Identity();
  ideal.translation() = spec_.origin_room_mm;
  return ideal;
}

Pose SimulatedRoom::true_T_room_from_ct_at_exposure(std::int64_t exposure_ns) const {
  // The link first, without the room's lock: the reader is lock-free, and walking its history
  // under the lock would keep the loop's thread (which takes it too) waiting on this one.
  RoomLinkSample sample;
  const bool linked = spec_.couch_link != nullptr;
  const bool read = linked && spec_.couch_link->read_at(exposure_ns, &sample);
  std::lock_guard lock(mutex_);
  if (!linked) return true_locked();
  return true_locked_with(read ? sample.couch_position : tracking::Vector6d::Zero());
}

Pose SimulatedRoom::true_locked() const { return true_locked_with(couch_position_locked()); }

Pose SimulatedRoom::true_locked_with(const tracking::Vector6d& couch_position) const {
  return calib::room_motion_of_couch(T_room_from_couch(), couch_position) * patient_locked();
}

double SimulatedRoom::residual_mm() const {
  std::lock_guard lock(mutex_);
  const Pose truth = true_locked();
  const Pose& plan = spec_.nominal_T_room_from_ct;
  const Eigen::Vector3d centre_ct = plan.inverse() * spec_.origin_room_mm;
  double sum = 0;
  for (int a = -1; a <= 1; ++a)
    for (int b = -1; b <= 1; ++b)
      for (int c = -1; c <= 1; ++c) {
        const Eigen::Vector3d p = centre_ct + 0.5 * spec_.residual_box_mm * Eigen::Vector3d(a, b, c);
        sum += (truth * p - plan * p).norm();
      }
  return sum / 27.0;
}

tracking::Vector6d SimulatedRoom::target_residual() const {
  std::lock_guard lock(mutex_);
  const Pose truth = true_locked();
  const Pose& plan = spec_.nominal_T_room_from_ct;
  // delta_between: T_truth = Translation(t + c) * exp(omega) * Translation(-c) * T_plan about the
  // registration origin c, so t is the origin's displacement and omega the rotation between them.
  return tracking::delta_between(plan, truth, spec_.origin_room_mm).as_vector();
}

drivers::DeviceStatus SimulatedRoom::CouchActuator::command(const tracking::Vector6d& correction,
                                                            drivers::Deadline deadline) {
  std::lock_guard lock(room_.mutex_);
  if (clocked_) room_.advance_for_command_locked(deadline);
  return room_.couch_.command(correction, deadline);
}

drivers::DeviceStatus SimulatedRoom::CouchActuator::readback(drivers::ActuatorState* state,
                                                             drivers::Deadline deadline) {
  std::lock_guard lock(room_.mutex_);
  return room_.couch_.readback(state, deadline);
}

void SimulatedRoom::CouchActuator::hold() {
  std::lock_guard lock(room_.mutex_);
  room_.couch_.hold();
}

}  // namespace lftrack::sim
