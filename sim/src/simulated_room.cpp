#include "lftrack/sim/simulated_room.hpp"

#include <chrono>

namespace lftrack::sim {

using tracking::Pose;
using tracking::PoseDelta;

SimulatedRoom::SimulatedRoom(const SimulatedRoomSpec& spec) : spec_(spec), couch_(spec.couch) {}

double SimulatedRoom::time_s_at(std::int64_t t_ns) const {
  return started_ ? 1e-9 * static_cast<double>(t_ns - epoch_ns_) : 0.0;
}

void SimulatedRoom::advance_to_ns(std::int64_t t_ns) {
  if (!started_) {
    started_ = true;
    epoch_ns_ = t_ns;
  }
  couch_.advance_to(time_s_at(t_ns));
}

Pose SimulatedRoom::patient_T_room_from_ct() const {
  const Pose set_up = tracking::apply_delta(spec_.nominal_T_room_from_ct,
                                            PoseDelta::from_vector(spec_.setup_error), spec_.origin_room_mm);
  return tracking::apply_delta(set_up, PoseDelta::from_vector(patient_offset(spec_.motion, time_s())),
                               spec_.origin_room_mm);
}

Pose SimulatedRoom::true_T_room_from_ct() const {
  return tracking::apply_delta(patient_T_room_from_ct(), PoseDelta::from_vector(couch_.position()),
                               spec_.origin_room_mm);
}

double SimulatedRoom::residual_mm() const {
  const Pose truth = true_T_room_from_ct();
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

drivers::DeviceStatus SimulatedRoom::CouchActuator::command(const tracking::Vector6d& correction,
                                                            drivers::Deadline deadline) {
  const std::int64_t deadline_ns =
      std::chrono::duration_cast<std::chrono::nanoseconds>(deadline.time_since_epoch()).count();
  if (room_.started_ && deadline_ns > room_.epoch_ns_) room_.advance_to_ns(deadline_ns);
  return room_.couch_.command(correction, deadline);
}

drivers::DeviceStatus SimulatedRoom::CouchActuator::readback(drivers::ActuatorState* state,
                                                             drivers::Deadline deadline) {
  return room_.couch_.readback(state, deadline);
}

}  // namespace lftrack::sim
