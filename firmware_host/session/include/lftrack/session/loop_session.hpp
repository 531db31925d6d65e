#pragma once
// One TrackingLoop assembled from a scene with everything around it: the scene's registration,
// the journal, the frame archive and the operator inputs, and the devices, which are either
//  - every device's simulated twin (`lftrack sim`, the closed-loop tests): set-up error,
//    patient motion, the simulator's detectors and the virtual couch, whatever devices the
//    scene names; or
//  - the scene's devices as it declares them (`lftrack run`): detectors through V4L2, GigE
//    Vision or an archived sequence, a couch through Modbus or a robot through CAN, made by the
//    drivers' factory (scene_devices.hpp); simulated detectors see a served couch through the
//    scene's sim.couch_link; or
//  - an archived sequence (`lftrack replay`): frames from disk, the recorded read-backs as the
//    actuator (track and report).
// Hardware in the loop (`lftrack sim --hil modbus|can`): the simulated room's couch is served by
// the virtual couch server (a libmodbus TCP server on 127.0.0.1), or moved by the virtual robot
// on a CAN link (a socket pair carrying struct can_frame), and the loop commands it through the
// real Modbus or CAN driver, so every command and read-back crosses the protocol.
// Whatever is simulated is made by the simulator the options name (room_simulator.hpp); the
// session itself holds no simulator code.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>

#include "lftrack/drivers/can_robot.hpp"
#include "lftrack/drivers/modbus_couch.hpp"
#include "lftrack/drivers/replay_frame_source.hpp"
#include "lftrack/loop/frame_archive.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/tracking_loop.hpp"
#include "lftrack/session/room_simulator.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/watch/igtl_server.hpp"
#include "lftrack/watch/monitor_server.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::session {

enum class HilProtocol { kNone, kModbus, kCan };

// Fault injection around a session's devices (the chaos soak, chaos_soak.hpp). A wrap hook, if
// set, is given the device the session built and returns the one the loop is to use instead;
// whoever sets the hooks owns what they return and keeps it alive as long as the session.
struct SessionHooks {
  std::function<drivers::FrameSource*(drivers::FrameSource*)> wrap_frames;
  std::function<drivers::Actuator*(drivers::Actuator*)> wrap_actuator;
  std::function<drivers::SurrogateSource*(drivers::SurrogateSource*)> wrap_surrogate;  // model imaging only
  loop::OperatorInput* operator_input = nullptr;  // polled with the session's own operators
  loop::CycleObserver* observer = nullptr;        // loop::LoopParts::observer
};

// kSimulated: every device is its simulated twin (lftrack sim). kScene: the scene's devices
// (lftrack run).
enum class SessionDevices { kSimulated, kScene };

struct LoopSessionOptions {
  std::int64_t cycles = 300;
  bool simulated_clock = false;  // true: as fast as possible, deterministic (see tracking_loop.hpp)
  bool status_line = false;
  bool announce_holds = false;           // without a status line: a line on stderr per HOLD/FAULT with its id
  std::filesystem::path journal;         // empty: no journal; an existing file is refused unless
  loop::JournalOptions journal_options;  // journal_options.overwrite
  bool overwrite_archive = false;        // an earlier archive in `archive` is replaced, not refused
  std::filesystem::path control_socket;  // empty: none
  bool terminal_operator = false;        // keys on a terminal's standard input
  std::optional<double> auto_resume_s;   // an unattended operator resumes this long into each HOLD
                                         // (check_auto_resume_s: finite, 0 to kMaxAutoResumeS);
                                         // refused, as is an unattended hooks.operator_input, where
                                         // the session opens a real device (kScene)
  std::filesystem::path light_field_dir;  // empty: the scene's default folder
  // The simulator that makes the simulated room (sim_devices::room_simulator()); null: none, and
  // a simulation, or a scene with simulated detectors, is refused.
  const RoomSimulator* simulator = nullptr;
  SimFrameSourceOptions frames;         // fault injection; wait_for_frames follows simulated_clock
  SimSurrogateFaults surrogate_faults;  // fault injection into the simulated surrogate
  std::filesystem::path archive;        // empty: frames not archived
  // Replay this archived sequence instead of simulating (simulated_clock: as fast as possible;
  // otherwise at the recorded pace).
  std::filesystem::path replay_sequence;
  HilProtocol hil = HilProtocol::kNone;  // simulation only; needs a scene with a couch
  SessionDevices devices = SessionDevices::kSimulated;
  std::uint64_t (*allocation_count)() = nullptr;
  SessionHooks hooks;
  // Watchers of the loop (watch/), fed through a CycleFeed the loop never waits for: the
  // operator's monitor page (its actions join the operator inputs) and the OpenIGTLink server.
  std::optional<watch::MonitorOptions> monitor;
  std::optional<watch::IgtlOptions> igtl;
};

// The room's geometry as the loop sees it: the scene's detectors, ROI windows, nominal pose and
// registration origin.
loop::LoopGeometry loop_geometry(const PreparedScene& scene);

// X = T_room_from_couch of a mounting or calibration (its centre defaults to the registration
// origin).
Eigen::Isometry3d couch_mounting(const CouchMountingSpec& mounting, const PreparedScene& scene);

// Checks the options that need no scene (auto-resume, the journal, archive and control-socket
// paths) without creating or removing anything: `lftrack sim/run/replay` call it before loading
// the CT, and create() calls it first.
Status check_session_options(const LoopSessionOptions& options);
// The scene's surrogate (tracking.imaging model) against the session's devices and clock: a
// watch no slower than the gate's frame age (the reading is a model cycle's frame); the
// simulated marker only in simulation; an OpenIGTLink tracker, whose readings are time stamped,
// only on the real clock. Checked again by LoopSession::create; a command checks it before it
// spends time preparing the scene.
Status check_session_surrogate(const Scene& scene, const LoopSessionOptions& options);
// Hardware in the loop (options.hil) against the scene and the session's devices: a simulation
// (neither the room's devices nor a replay) of a scene with a couch. Checked again by
// LoopSession::create; a command checks it before it spends time preparing the scene.
Status check_session_hil(const Scene& scene, const LoopSessionOptions& options);

class LoopSession {
 public:
  ~LoopSession();
  // Builds (or loads) the renderers' light fields, the registration on `pool`, the room and its
  // devices, and the loop. `scene` and `pool` must outlive the session.
  static Result<std::unique_ptr<LoopSession>> create(const PreparedScene& scene,
                                                     const LoopSessionOptions& options,
                                                     tracking::ThreadPool* pool);
  // Runs the loop; closes the journal and the archive. A journal that failed during the run is
  // reported in the summary's journal_error (the loop held when it failed).
  Result<loop::LoopSummary> run();
  void request_stop();
  RoomSimulation* simulation();  // the simulated room; null without one
  const RoomSimulation* simulation() const;
  const drivers::ReplayFrameSource* replay() const;  // null when simulating
  const loop::FrameArchive* archive() const;         // null without one
  std::filesystem::path journal_path() const;        // the journal written (empty: none)
  bool journal_failed() const;                       // the journal's writer failed (disk full, I/O error)
  const drivers::ModbusCouch* modbus_couch() const;  // the Modbus couch driver (HIL or run); null otherwise
  const drivers::CanRobot* can_robot() const;        // the CAN robot driver (HIL or run); null otherwise
  const watch::MonitorServer* monitor() const;       // null without --monitor
  const watch::IgtlServer* igtl() const;             // null without --igtl
  const watch::CycleHub* hub() const;                // null without watchers

  struct Parts;  // defined in loop_session.cpp

 private:
  explicit LoopSession(std::unique_ptr<Parts> parts);
  std::unique_ptr<Parts> parts_;
};

}  // namespace lftrack::session
