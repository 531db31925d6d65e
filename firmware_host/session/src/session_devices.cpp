// The devices of a loop session (session_parts.hpp): its frame source and what moves the patient,
// from the scene's devices through the drivers' factory, or the simulated room's, made by the
// session's simulator (room_simulator.hpp: its detectors and couch, in process or behind its
// protocol for hardware in the loop).

#include <spdlog/spdlog.h>

#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/session/actuator_lock.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "session_parts.hpp"

namespace lftrack::session {
Status check_session_hil(const Scene& scene, const LoopSessionOptions& o) {
  if (o.hil == HilProtocol::kNone) return {};
  if (o.devices != SessionDevices::kSimulated || !o.replay_sequence.empty())
    return invalid_argument("hardware in the loop (--hil) is a simulation: it needs `lftrack sim`");
  if (!actuator_moves(scene))
    return invalid_argument(
        scene.where("actuator") +
        ": hardware in the loop needs a scene with a couch (actuator.type other than none)");
  return {};
}

bool needs_simulated_room(const PreparedScene& p, const LoopSessionOptions& o) {
  return o.replay_sequence.empty() &&
         (o.devices == SessionDevices::kSimulated || frames_are_simulated(p.scene));
}

Status check_simulator(const PreparedScene& p, const LoopSessionOptions& o) {
  if (o.simulator != nullptr || !needs_simulated_room(p, o)) return {};
  return failed_precondition(o.devices == SessionDevices::kSimulated
                                 ? std::string("a simulation needs the simulator, and this program has none")
                                 : p.scene.where("detectors") +
                                       ": the scene's detectors are simulated, and this program has no "
                                       "simulator (lftrack run drives a room's own devices; lftrack sim "
                                       "--room runs a room with simulated detectors)");
}

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
  // A simulator is given: LoopSession::create checked it (check_simulator) before anything was built.
  drivers::SimulatedSourceSpec simulated;
  simulated.make = [&p, &o, pool, parts]() -> Result<std::unique_ptr<drivers::FrameSource>> {
    auto room = o.simulator->make_room(p, o, pool);
    if (!room.ok()) return room.status();
    if (*room == nullptr) return internal_error("the simulator made no room");
    parts->room = std::move(room).value();
    return parts->room->make_detectors();
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
  LFTRACK_RETURN_IF_ERROR(check_session_hil(p.scene, o));
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
  if (!couch) return Spec();  // with --hil, refused above
  if (parts->room == nullptr)
    return failed_precondition("the virtual couch moves a simulated patient: it needs simulated detectors");
  auto spec = parts->room->couch_actuator();  // the virtual couch, or with --hil behind its protocol
  if (!spec.ok()) return spec.status();
  return Spec(std::move(spec).value());
}

}  // namespace lftrack::session
