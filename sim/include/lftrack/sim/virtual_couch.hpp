#pragma once
// A virtual treatment couch with the dynamics a real one has: a command takes effect after a
// latency, then the couch moves towards its target at limited speed (translation and rotation
// separately), within a range of travel. Time is the simulator's, advanced explicitly, so the
// closed loop is deterministic and testable without sleeping.
//
// Commands are corrections relative to the last commanded target (drivers::Actuator). A command
// that would take the target outside the range is refused (kFault) and changes nothing; hold()
// stops the couch where it is and drops commands not yet in effect.

#include <array>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/drivers/actuator_dynamics.hpp"

namespace lftrack::sim {

// The virtual couch moves as the host assumes its actuator moves (the scene's `actuator`).
using VirtualCouchSpec = drivers::ActuatorDynamics;

// Whether `position` (couch coordinates, mm and rad) is within the couch's travel: each
// translation within range_mm of zero, each rotation component within range_deg.
bool within_travel(const VirtualCouchSpec& spec, const tracking::Vector6d& position);

class VirtualCouch final : public drivers::Actuator {
 public:
  explicit VirtualCouch(const VirtualCouchSpec& spec = {}) : spec_(spec) {}

  Status open() override { return {}; }
  drivers::DeviceStatus command(const tracking::Vector6d& correction, drivers::Deadline deadline) override;
  drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline deadline) override;
  void hold() override;
  void close() override {}

  // Before the first command: the couch stands at `position` (a couch controller restarted
  // where the couch stopped). Its target is that position; nothing is pending.
  void place_at(const tracking::Vector6d& position);
  // The simulator's clock: moves the couch to where it is at time t (s; never backwards).
  void advance_to(double t_s);
  double time_s() const { return now_s_; }
  const tracking::Vector6d& position() const { return position_; }
  const tracking::Vector6d& target() const { return commanded_; }

 private:
  struct Pending {
    double effective_s = 0;
    tracking::Vector6d target = tracking::Vector6d::Zero();
  };
  void move_towards(const tracking::Vector6d& target, double dt_s);

  VirtualCouchSpec spec_;
  double now_s_ = 0;
  tracking::Vector6d position_ = tracking::Vector6d::Zero();
  tracking::Vector6d active_target_ = tracking::Vector6d::Zero();  // in effect now
  tracking::Vector6d commanded_ = tracking::Vector6d::Zero();      // last accepted command
  std::array<Pending, 32> pending_{};  // commands waiting out the latency, oldest first
  int pending_count_ = 0;
};

}  // namespace lftrack::sim
