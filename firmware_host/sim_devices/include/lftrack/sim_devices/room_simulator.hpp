#pragma once
// The simulator's devices as the session's RoomSimulator (lftrack/session/room_simulator.hpp): the
// simulated room of a scene (its patient, set-up error, motion and couch), its detectors
// (SimFrameSource), the virtual couch in process or behind its protocol for hardware in the loop
// (the Modbus server, or the robot on a CAN link), and the patient's chest marker, in process or
// served by the tracker's twin over OpenIGTLink.
//
// A program that simulates gives the session room_simulator() (LoopSessionOptions::simulator):
// `lftrack sim`, and for now `lftrack run` too (a room scene's simulated detectors beside a served
// couch); `replay` gives none. The accessors below reach into a session's simulated room, for
// tests and the chaos soak's fault injection.

#include "lftrack/session/loop_session.hpp"
#include "lftrack/session/room_simulator.hpp"
#include "lftrack/sim/modbus_couch_server.hpp"
#include "lftrack/sim/simulated_room.hpp"
#include "lftrack/sim/virtual_robot.hpp"

namespace lftrack::sim_devices {

// The simulator (stateless; one for the program).
const session::RoomSimulator* room_simulator();

// The simulated room of a scene: its planned pose and registration origin, the patient's set-up
// error and motion, the couch's dynamics and mounting (actuator.mounting; ideal: about the
// registration origin), the residual's box; no couch link. The session's room and the served
// detectors' (`lftrack serve detectors`) are both made from it.
sim::SimulatedRoomSpec scene_room_spec(const session::PreparedScene& scene);

// A session's simulated room; null where it has none (a replay, or the room's real devices).
const sim::SimulatedRoom* simulated_room(const session::LoopSession& session);
// Hardware in the loop: the room couch's Modbus server, or the virtual robot on its CAN link, for
// fault injection; null where the session has none.
sim::ModbusCouchServer* modbus_couch_server(session::LoopSession& session);
sim::VirtualRobot* virtual_robot(session::LoopSession& session);

}  // namespace lftrack::sim_devices
