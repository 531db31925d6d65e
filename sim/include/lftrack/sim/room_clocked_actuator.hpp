#pragma once

#include <chrono>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/sim/simulated_room.hpp"

namespace lftrack::sim {

// A hardware-in-the-loop couch: before each command crosses the protocol, the simulated room is
// moved on to the cycle's deadline, as the in-process couch does (simulated_room.hpp), so a HIL
// run follows the same timing. On the loop's simulated clock the deadlines are virtual, and the
// driver gets a real one instead (protocol requests still time out).
class RoomClockedActuator final : public drivers::Actuator {
 public:
  RoomClockedActuator(sim::SimulatedRoom* room, drivers::Actuator* driver, bool simulated_clock)
      : room_(room), driver_(driver), simulated_clock_(simulated_clock) {}
  Status open() override { return driver_->open(); }
  drivers::DeviceStatus command(const tracking::Vector6d& correction, drivers::Deadline deadline) override {
    room_->advance_for_command(deadline);
    return driver_->command(correction, real(deadline));
  }
  drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline deadline) override {
    return driver_->readback(state, real(deadline));
  }
  void hold() override { driver_->hold(); }
  void set_beam_permit(bool permit) override { driver_->set_beam_permit(permit); }
  void close() override { driver_->close(); }

 private:
  drivers::Deadline real(drivers::Deadline deadline) const {
    return simulated_clock_ ? std::chrono::steady_clock::now() + std::chrono::seconds(1) : deadline;
  }
  sim::SimulatedRoom* room_;
  drivers::Actuator* driver_;
  bool simulated_clock_;
};

}  // namespace lftrack::sim
