// The devices of a loop session (session_parts.hpp): its frame source and what moves the patient,
// from the scene's devices through the drivers' factory, or the simulator's (the simulated room's
// detectors and couch, in process or behind its protocol for hardware in the loop).

#include <spdlog/spdlog.h>

#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/drivers/forwarding_actuator.hpp"
#include "lftrack/host/actuator_lock.hpp"
#include "lftrack/host/scene_devices.hpp"
#include "lftrack/sim/room_clocked_actuator.hpp"
#include "session_parts.hpp"

namespace lftrack::session {
namespace {

// The simulated room of a scene: its patient, set-up error and couch; with `couch_link`, the
// couch is another process's.
Result<std::unique_ptr<sim::SimulatedRoom>> make_room(const PreparedScene& p, const LoopSessionOptions& o) {
  sim::SimulatedRoomSpec room;
  room.nominal_T_room_from_ct = p.nominal_T_room_from_ct;
  room.origin_room_mm = p.registration_origin_room_mm();
  room.setup_error = p.scene.motion.setup_error;
  room.motion = p.scene.motion.motion;
  room.couch = p.scene.actuator.dynamics;
  if (p.scene.actuator.mounting) room.couch_T_room_from_couch = couch_mounting(*p.scene.actuator.mounting, p);
  room.residual_box_mm = p.scene.registration.tre_box_mm;
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

// The simulator's side of a hardware-in-the-loop protocol (the couch's Modbus server, or the
// robot on a CAN link) and the driver the factory makes for it, clocked by the room.
Result<drivers::ActuatorSpec> hil_actuator_spec(const PreparedScene& p, const LoopSessionOptions& o,
                                                LoopSession::Parts* parts) {
  drivers::ActuatorSpec driver_spec;
  std::string endpoint;
  if (o.hil == HilProtocol::kModbus) {
    auto server = sim::ModbusCouchServer::start(&parts->room->couch_device());
    if (!server.ok()) return server.status();
    parts->couch_server = std::move(server).value();
    drivers::ModbusActuatorSpec couch;
    couch.options.port = parts->couch_server->port();
    // On the real clock a reply must come within the cycle; on the simulated clock the cycle has
    // no wall-clock length, and the budget only has to outlast a loaded host's scheduling (a
    // server thread preempted past 20 ms made a simulated run hold).
    couch.options.response_timeout_s =
        o.simulated_clock ? 0.25 : std::min(0.02, 0.5e-3 * p.scene.loop.period_ms);
    driver_spec = couch;
  } else {
    auto link = sim::can_socket_pair();
    if (!link.ok()) return link.status();
    auto robot = sim::VirtualRobot::start(&parts->room->couch_device(), (*link)[1]);
    if (!robot.ok()) return robot.status();
    parts->robot = std::move(robot).value();
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
  parts->device_actuator = std::move(driver).value();
  if (const auto* modbus = dynamic_cast<const drivers::ModbusCouch*>(parts->device_actuator.get()))
    endpoint = modbus->endpoint();
  spdlog::info("hardware in the loop: the couch is {}", endpoint);
  drivers::VirtualActuatorSpec clocked;
  clocked.make = [parts,
                  simulated_clock = o.simulated_clock]() -> Result<std::unique_ptr<drivers::Actuator>> {
    return std::unique_ptr<drivers::Actuator>(
        new sim::RoomClockedActuator(parts->room.get(), parts->device_actuator.get(), simulated_clock));
  };
  return drivers::ActuatorSpec(std::move(clocked));
}

}  // namespace

Result<drivers::FrameSourceSpec> frame_source_spec(const PreparedScene& p, const LoopSessionOptions& o,
                                                   tracking::ThreadPool* pool, LoopSession::Parts* parts) {
  std::vector<drivers::DetectorShape> shapes;
  for (const DetectorSpec& d : p.scene.detectors) shapes.push_back({d.view.name, d.view.rows, d.view.cols});
  if (!o.replay_sequence.empty()) {  // lftrack replay --sequence DIR
    drivers::ReplaySourceSpec replay;
    replay.sequence = o.replay_sequence;
    replay.detectors = shapes;
    replay.options.realtime = !o.simulated_clock;
    return drivers::FrameSourceSpec(std::move(replay));
  }
  if (o.devices == SessionDevices::kScene && !frames_are_simulated(p.scene))
    return device_frame_source_spec(p.scene);
  drivers::SimulatedSourceSpec simulated;
  simulated.make = [&p, &o, pool, parts]() -> Result<std::unique_ptr<drivers::FrameSource>> {
    auto patient = make_scene_patient(p, o.light_field_dir, pool);  // realistic physics (null: ideal frames)
    if (!patient.ok()) return patient.status();
    if (!*patient) {
      auto frame_renderer = make_sim_frame_renderer(p, o.light_field_dir, pool);
      if (!frame_renderer.ok()) return frame_renderer.status();
      parts->frame_renderer = *frame_renderer;
    }
    auto room = make_room(p, o);
    if (!room.ok()) return room.status();
    parts->room = std::move(room).value();
    SimFrameSourceOptions frame_options = o.frames;
    frame_options.wait_for_frames = o.simulated_clock;
    frame_options.detectors.margin_px = sim_frame_margin_px(p);
    return std::unique_ptr<drivers::FrameSource>(
        new SimFrameSource(p, parts->frame_renderer, parts->room.get(), frame_options, *patient));
  };
  return drivers::FrameSourceSpec(std::move(simulated));
}

// What moves the patient, if anything: the recorded read-backs of a replayed sequence, the
// scene's Modbus couch or CAN robot (lftrack run), or the simulated room's couch, in process or
// behind its protocol (--hil).
Result<std::optional<drivers::ActuatorSpec>> session_actuator_spec(const PreparedScene& p,
                                                                   const LoopSessionOptions& o,
                                                                   LoopSession::Parts* parts) {
  using Spec = std::optional<drivers::ActuatorSpec>;
  if (o.hil != HilProtocol::kNone && (o.devices != SessionDevices::kSimulated || !o.replay_sequence.empty()))
    return invalid_argument("hardware in the loop (--hil) is a simulation: it needs `lftrack sim`");
  if (parts->replay_frames != nullptr) {
    if (!parts->replay_frames->sequence().has_actuator) return Spec();
    return Spec(drivers::RecordedActuatorSpec{parts->replay_frames});
  }
  if (o.devices == SessionDevices::kScene && actuator_is_device(p.scene)) {
    auto spec = device_actuator_spec(p.scene);
    if (!spec.ok()) return spec.status();
    auto lock = ActuatorLock::acquire(p.scene);  // before it is opened: one program drives a couch
    if (!lock.ok()) return lock.status();
    parts->actuator_lock = std::move(lock).value();
    spdlog::info("the actuator is {}", describe_actuator(p.scene.actuator));
    return Spec(std::move(spec).value());
  }
  // Simulated: a scene's couch or robot is simulated by the room's couch (its twin).
  const bool couch =
      o.devices == SessionDevices::kSimulated ? actuator_moves(p.scene) : actuator_is_virtual(p.scene);
  if (!couch) {
    if (o.hil != HilProtocol::kNone)
      return invalid_argument(
          "hardware in the loop needs a scene with a couch (actuator.type other than none)");
    return Spec();
  }
  if (parts->room == nullptr)
    return failed_precondition("the virtual couch moves a simulated patient: it needs simulated detectors");
  if (o.hil != HilProtocol::kNone) {
    auto spec = hil_actuator_spec(p, o, parts);
    if (!spec.ok()) return spec.status();
    return Spec(std::move(spec).value());
  }
  if (actuator_is_device(p.scene))
    spdlog::info("the scene's {} is simulated by its twin, the virtual couch",
                 describe_actuator(p.scene.actuator));
  drivers::VirtualActuatorSpec simulated;
  simulated.make = [room = parts->room.get()]() -> Result<std::unique_ptr<drivers::Actuator>> {
    // The room owns its couch; the session borrows it.
    return std::unique_ptr<drivers::Actuator>(new drivers::ForwardingActuator(&room->couch_actuator()));
  };
  return Spec(std::move(simulated));
}

}  // namespace lftrack::session
