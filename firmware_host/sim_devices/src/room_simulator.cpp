// The simulator's devices as the session's RoomSimulator (room_simulator.hpp): the simulated room
// of a scene and what the session makes from it.

#include "lftrack/sim_devices/room_simulator.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "lftrack/drivers/can_robot.hpp"
#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/drivers/forwarding_actuator.hpp"
#include "lftrack/drivers/modbus_couch.hpp"
#include "lftrack/loop/realtime_setup.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/sim/room_clocked_actuator.hpp"
#include "lftrack/sim/room_link.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"
#include "lftrack/sim_devices/sim_frame_source.hpp"
#include "lftrack/sim_devices/sim_surrogate_source.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"
#include "room_parts.hpp"

namespace lftrack::sim_devices {

using session::actuator_is_device;
using session::couch_mounting;
using session::describe_actuator;
using session::HilProtocol;
using session::LoopSession;
using session::LoopSessionOptions;
using session::PreflightReport;
using session::PreparedScene;
using session::RoomSimulation;
using session::SessionDevices;
using session::SimFrameSourceOptions;
using session::SurrogateSpec;

sim::SimulatedRoomSpec scene_room_spec(const PreparedScene& p) {
  sim::SimulatedRoomSpec room;
  room.nominal_T_room_from_ct = p.nominal_T_room_from_ct;
  room.origin_room_mm = p.registration_origin_room_mm();
  room.setup_error = p.scene.motion.setup_error;
  room.motion = p.scene.motion.motion;
  room.couch = p.scene.actuator.dynamics;
  if (p.scene.actuator.mounting) room.couch_T_room_from_couch = couch_mounting(*p.scene.actuator.mounting, p);
  room.residual_box_mm = p.scene.registration.tre_box_mm;
  return room;
}

namespace {

// The simulated room of a scene (scene_room_spec); with `couch_link`, the couch is another
// process's.
Result<std::unique_ptr<sim::SimulatedRoom>> make_room(const PreparedScene& p, const LoopSessionOptions& o) {
  sim::SimulatedRoomSpec room = scene_room_spec(p);
  if (o.devices == SessionDevices::kScene && actuator_is_device(p.scene)) {
    // Simulated detectors and a real protocol's couch: the patient must move with that couch.
    if (p.scene.sim.couch_link.empty())
      return failed_precondition(
          "simulated detectors with a " + p.scene.actuator.type +
          " actuator: the simulated patient would never move with it; name the served couch's room link as "
          "sim.couch_link (lftrack serve couch|robot --room FILE), or use real detectors");
    auto link = sim::RoomLinkReader::open(p.scene.sim.couch_link);
    if (!link.ok()) return link.status().with_context("sim.couch_link");
    room.couch_link = std::move(link).value();
  }
  return std::make_unique<sim::SimulatedRoom>(room);
}

class SceneRoomSimulator final : public session::RoomSimulator {
 public:
  Result<std::unique_ptr<RoomSimulation>> make_room(const PreparedScene& p, const LoopSessionOptions& o,
                                                    tracking::ThreadPool* pool) const override {
    auto room = sim_devices::make_room(p, o);
    if (!room.ok()) return room.status();
    return std::unique_ptr<RoomSimulation>(new SceneRoom(p, o, pool, std::move(room).value()));
  }
  void preflight(const PreparedScene& p, const LoopSessionOptions& o, PreflightReport* r) const override {
    room_preflight(p, o, r);
  }
};

const SceneRoom* scene_room(const LoopSession& session) {
  return dynamic_cast<const SceneRoom*>(session.simulation());
}
SceneRoom* scene_room(LoopSession& session) {
  return dynamic_cast<SceneRoom*>(session.simulation());
}

}  // namespace

SceneRoom::SceneRoom(const PreparedScene& p, const LoopSessionOptions& o, tracking::ThreadPool* pool,
                     std::unique_ptr<sim::SimulatedRoom> room)
    : scene_(p),
      options_{o.light_field_dir, o.frames, o.surrogate_faults, o.simulated_clock, o.hil},
      pool_(pool),
      room_(std::move(room)),
      truth_(room_.get()) {}

SceneRoom::~SceneRoom() = default;

Result<std::unique_ptr<drivers::FrameSource>> SceneRoom::make_detectors() {
  const PreparedScene& p = scene_;
  auto patient =
      make_scene_patient(p, options_.light_field_dir, pool_);  // realistic physics (null: ideal frames)
  if (!patient.ok()) return patient.status();
  if (!*patient) {
    auto frame_renderer = make_sim_frame_renderer(p, options_.light_field_dir, pool_);
    if (!frame_renderer.ok()) return frame_renderer.status();
    frame_renderer_ = *frame_renderer;
  }
  SimFrameSourceOptions frame_options = options_.frames;
  frame_options.wait_for_frames = options_.simulated_clock;
  frame_options.detectors.margin_px = sim_frame_margin_px(p);
  return std::unique_ptr<drivers::FrameSource>(
      new SimFrameSource(p, frame_renderer_, room_.get(), frame_options, *patient));
}

Result<drivers::ActuatorSpec> SceneRoom::couch_actuator() {
  if (options_.hil != HilProtocol::kNone) return hil_actuator_spec();
  if (actuator_is_device(scene_.scene))
    spdlog::info("the scene's {} is simulated by its twin, the virtual couch",
                 describe_actuator(scene_.scene.actuator));
  drivers::VirtualActuatorSpec simulated;
  simulated.make = [room = room_.get()]() -> Result<std::unique_ptr<drivers::Actuator>> {
    // The room owns its couch; the session borrows it.
    return std::unique_ptr<drivers::Actuator>(new drivers::ForwardingActuator(&room->couch_actuator()));
  };
  return drivers::ActuatorSpec(std::move(simulated));
}

// The simulator's side of a hardware-in-the-loop protocol (the couch's Modbus server, or the
// robot on a CAN link) and the driver the factory makes for it, clocked by the room.
Result<drivers::ActuatorSpec> SceneRoom::hil_actuator_spec() {
  const PreparedScene& p = scene_;
  const RoomOptions& o = options_;
  drivers::ActuatorSpec driver_spec;
  std::string endpoint;
  if (o.hil == HilProtocol::kModbus) {
    auto server = sim::ModbusCouchServer::start(&room_->couch_device());
    if (!server.ok()) return server.status();
    couch_server_ = std::move(server).value();
    drivers::ModbusActuatorSpec couch;
    couch.options.port = couch_server_->port();
    // On the real clock a reply must come within the cycle; on the simulated clock the cycle has
    // no wall-clock length, and the budget only has to outlast a loaded host's scheduling (a
    // server thread preempted past 20 ms made a simulated run hold).
    couch.options.response_timeout_s =
        o.simulated_clock ? 0.25 : std::min(0.02, 0.5e-3 * p.scene.loop.period_ms);
    driver_spec = couch;
  } else {
    auto link = sim::can_socket_pair();
    if (!link.ok()) return link.status();
    auto robot = sim::VirtualRobot::start(&room_->couch_device(), (*link)[1]);
    if (!robot.ok()) return robot.status();
    robot_ = std::move(robot).value();
    drivers::CanRobotOptions can_options;
    // As the Modbus reply's budget above: on the simulated clock the heartbeat's wall-clock
    // timeout only has to outlast a loaded host's scheduling of the robot's thread (0.3 s, six
    // heartbeats, is the real clock's).
    if (o.simulated_clock) can_options.heartbeat_timeout_s = 1.0;
    driver_spec = drivers::CanActuatorSpec{can_options, (*link)[0]};
    endpoint = "CAN node 1 over a socket pair";
  }
  auto driver = drivers::make_actuator(std::move(driver_spec));
  if (!driver.ok()) return driver.status();
  device_actuator_ = std::move(driver).value();
  if (const auto* modbus = dynamic_cast<const drivers::ModbusCouch*>(device_actuator_.get()))
    endpoint = modbus->endpoint();
  spdlog::info("hardware in the loop: the couch is {}", endpoint);
  drivers::VirtualActuatorSpec clocked;
  clocked.make = [this, simulated_clock = o.simulated_clock]() -> Result<std::unique_ptr<drivers::Actuator>> {
    return std::unique_ptr<drivers::Actuator>(
        new sim::RoomClockedActuator(room_.get(), device_actuator_.get(), simulated_clock));
  };
  return drivers::ActuatorSpec(std::move(clocked));
}

std::unique_ptr<drivers::SurrogateSource> SceneRoom::chest_marker() {
  return std::make_unique<SimSurrogateSource>(scene_.scene.surrogate.sim, room_.get(),
                                              options_.surrogate_faults);
}

// lftrack sim with surrogate.source igtl: the simulated chest marker (surrogate.sim, faults
// included) served by the tracker's twin on a loopback port of its own, for the session's
// OpenIGTLink client to read: the real protocol, its threads and time stamps, in the loop.
Result<int> SceneRoom::serve_chest_marker() {
  const SurrogateSpec& s = scene_.scene.surrogate;
  sim::TrackerTwinOptions twin;
  twin.device = s.igtl_device.empty() ? "Marker" : s.igtl_device;
  twin.rate_hz = std::min(1000.0, scene_.scene.loop.imaging.surrogate.rate_hz);
  twin.on_thread_start = [] { (void)loop::lower_current_thread_priority(); };
  auto marker = std::make_shared<SimSurrogateSource>(s.sim, room_.get(), options_.surrogate_faults);
  const sim::SimulatedRoom* room = room_.get();
  const Eigen::Vector3d axis = s.igtl_axis;
  auto served = sim::TrackerTwin::start(twin, [=](std::int64_t t_ns, Eigen::Vector3d* position) {
    const std::int64_t epoch = room->epoch_ns();
    if (epoch < 0 || t_ns < epoch) return false;  // the room starts at its first exposure
    const double t_s = 1e-9 * double(t_ns - epoch);
    if (marker->stopped_at(t_s)) return false;
    *position = axis * marker->reading_at(t_s);
    return true;
  });
  if (!served.ok()) return served.status().with_context("the tracker's twin");
  tracker_twin_ = std::move(served).value();
  spdlog::info(
      "surrogate: the simulated chest marker served over OpenIGTLink on 127.0.0.1:{} ({} \"{}\" at {:g} Hz), "
      "read back by the tracker's client",
      tracker_twin_->port(), "TRANSFORM", twin.device, twin.rate_hz);
  return tracker_twin_->port();
}

const session::RoomSimulator* room_simulator() {
  static const SceneRoomSimulator simulator;
  return &simulator;
}

const sim::SimulatedRoom* simulated_room(const LoopSession& session) {
  const SceneRoom* room = scene_room(session);
  return room != nullptr ? &room->room() : nullptr;
}

sim::ModbusCouchServer* modbus_couch_server(LoopSession& session) {
  SceneRoom* room = scene_room(session);
  return room != nullptr ? room->couch_server() : nullptr;
}

sim::VirtualRobot* virtual_robot(LoopSession& session) {
  SceneRoom* room = scene_room(session);
  return room != nullptr ? room->robot() : nullptr;
}

}  // namespace lftrack::sim_devices
