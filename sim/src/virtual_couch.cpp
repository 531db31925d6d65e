#include "lftrack/sim/virtual_couch.hpp"

#include <algorithm>
#include <cmath>

namespace lftrack::sim {

using drivers::DeviceStatus;
using tracking::Vector6d;

bool within_travel(const VirtualCouchSpec& spec, const Vector6d& position) {
  return position.head<3>().cwiseAbs().maxCoeff() <= spec.range_mm &&
         tracking::rad_to_deg(position.tail<3>().cwiseAbs().maxCoeff()) <= spec.range_deg;
}

DeviceStatus VirtualCouch::command(const Vector6d& correction, drivers::Deadline) {
  if (!correction.allFinite()) return DeviceStatus::kFault;
  const Vector6d target = commanded_ + correction;
  if (!within_travel(spec_, target)) return DeviceStatus::kFault;
  if (pending_count_ == int(pending_.size()))
    return DeviceStatus::kFault;  // commands faster than it can take
  pending_[std::size_t(pending_count_++)] = {now_s_ + spec_.latency_s, target};
  commanded_ = target;
  return DeviceStatus::kOk;
}

DeviceStatus VirtualCouch::readback(drivers::ActuatorState* state, drivers::Deadline) {
  state->position = position_;
  state->target = commanded_;
  state->moving = (active_target_ - position_).cwiseAbs().maxCoeff() > 1e-9 || pending_count_ > 0;
  state->fault = false;
  return DeviceStatus::kOk;
}

void VirtualCouch::place_at(const Vector6d& position) {
  position_ = active_target_ = commanded_ = position;
  pending_count_ = 0;
}

void VirtualCouch::hold() {
  pending_count_ = 0;
  active_target_ = position_;
  commanded_ = position_;
}

void VirtualCouch::move_towards(const Vector6d& target, double dt_s) {
  if (dt_s <= 0) return;
  const Vector6d d = target - position_;
  const double dist_mm = d.head<3>().norm(), angle_rad = d.tail<3>().norm();
  // One time scale for both parts, so the couch moves along a straight line in the 6 numbers.
  const double t_needed =
      std::max(dist_mm / spec_.max_speed_mm_s, tracking::rad_to_deg(angle_rad) / spec_.max_speed_deg_s);
  position_ = t_needed <= dt_s ? target : Vector6d(position_ + d * (dt_s / t_needed));
}

void VirtualCouch::advance_to(double t_s) {
  while (now_s_ < t_s) {
    // Up to the next command taking effect, or to t.
    const double next = pending_count_ > 0 ? std::min(t_s, std::max(now_s_, pending_[0].effective_s)) : t_s;
    move_towards(active_target_, next - now_s_);
    now_s_ = next;
    while (pending_count_ > 0 && pending_[0].effective_s <= now_s_) {
      active_target_ = pending_[0].target;
      std::move(pending_.begin() + 1, pending_.begin() + pending_count_, pending_.begin());
      --pending_count_;
    }
    if (next >= t_s) break;
  }
}

}  // namespace lftrack::sim
