#pragma once
// The simulated room of one session (room_simulator.cpp makes it): private to sim_devices.

#include <filesystem>
#include <memory>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/session/loop_session.hpp"
#include "lftrack/session/preflight.hpp"
#include "lftrack/session/room_simulator.hpp"
#include "lftrack/sim/modbus_couch_server.hpp"
#include "lftrack/sim/simulated_room.hpp"
#include "lftrack/sim/tracker_twin.hpp"
#include "lftrack/sim/virtual_robot.hpp"

namespace lftrack::sim_devices {

// The simulated room's truth as the loop reads it (the loop never sees sim/).
class RoomTruth final : public loop::SimulatedTruth {
 public:
  explicit RoomTruth(const sim::SimulatedRoom* room) : room_(room) {}
  double residual_mm() const override { return room_->residual_mm(); }
  tracking::Vector6d target_residual() const override { return room_->target_residual(); }

 private:
  const sim::SimulatedRoom* room_;
};

// What the room owns, in the order it is destroyed in reverse: the servers and the tracker's
// twin before the driver that talks to them, all of them before the room they serve.
class SceneRoom final : public session::RoomSimulation {
 public:
  SceneRoom(const session::PreparedScene& scene, const session::LoopSessionOptions& options,
            tracking::ThreadPool* pool, std::unique_ptr<sim::SimulatedRoom> room);
  ~SceneRoom() override;

  Result<std::unique_ptr<drivers::FrameSource>> make_detectors() override;
  Result<drivers::ActuatorSpec> couch_actuator() override;
  const drivers::Actuator* protocol_driver() const override { return device_actuator_.get(); }
  std::unique_ptr<drivers::SurrogateSource> chest_marker() override;
  Result<int> serve_chest_marker() override;
  const loop::SimulatedTruth* truth() const override { return &truth_; }

  const sim::SimulatedRoom& room() const { return *room_; }
  sim::ModbusCouchServer* couch_server() { return couch_server_.get(); }
  sim::VirtualRobot* robot() { return robot_.get(); }

 private:
  Result<drivers::ActuatorSpec> hil_actuator_spec();

  // What the room takes from the session's options (copied: the options need not outlive it).
  struct RoomOptions {
    std::filesystem::path light_field_dir;
    session::SimFrameSourceOptions frames;
    session::SimSurrogateFaults surrogate_faults;
    bool simulated_clock = false;
    session::HilProtocol hil = session::HilProtocol::kNone;
  };

  const session::PreparedScene& scene_;
  RoomOptions options_;
  tracking::ThreadPool* pool_;
  std::unique_ptr<sim::SimulatedRoom> room_;
  RoomTruth truth_;
  std::shared_ptr<const tracking::DrrRenderer> frame_renderer_;  // ideal frames only
  std::unique_ptr<drivers::Actuator> device_actuator_;           // HIL: the Modbus or CAN driver
  std::unique_ptr<sim::ModbusCouchServer> couch_server_;         // HIL: serves the room's couch
  std::unique_ptr<sim::VirtualRobot> robot_;                     // HIL over CAN: moves the room's couch
  std::unique_ptr<sim::TrackerTwin> tracker_twin_;               // surrogate.source igtl in a simulation
};

// RoomSimulator::preflight (room_preflight.cpp).
void room_preflight(const session::PreparedScene& scene, const session::LoopSessionOptions& options,
                    session::PreflightReport* report);

}  // namespace lftrack::sim_devices
