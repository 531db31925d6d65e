#pragma once
// The simulated room as the session sees it (issue 55). The session assembles a run from the
// drivers' factory; where a scene's devices are simulated, it asks a RoomSimulator it is given
// (LoopSessionOptions::simulator) for them. The simulator's devices (its detectors, the virtual
// couch and robot, the hardware-in-the-loop servers, the patient's chest marker) live in
// lftrack::sim_devices (firmware_host/sim_devices), which implements this interface: the session
// library never links their code, and a program that gives no simulator (null) has none. A
// session without one refuses a scene whose devices are simulated, before anything is made.
//
// The fault options below are what a test or the chaos soak asks of the simulated devices; the
// session passes them on and reads none of them.

#include <cstdint>
#include <memory>

#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/drivers/surrogate_source.hpp"
#include "lftrack/loop/loop_parts.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::session {

struct PreparedScene;
struct LoopSessionOptions;
struct PreflightReport;

struct SimDetectorsOptions {
  int margin_px = 16;  // exposed border around each ROI window (sim_frame_margin_px)
  // The rest of each detector too, coarser, as a real panel reads out every pixel; false leaves
  // it at 0 (unexposed).
  bool whole_detector = true;
};

struct SimFrameSourceOptions {
  // Wait for each frame however long it takes (a loop on a simulated clock, whose deadlines say
  // nothing about the wall clock); otherwise acquire() gives up at its deadline.
  bool wait_for_frames = false;
  // The ROI windows' margin (0 for light-field frames) and whether the rest of each detector is
  // exposed too.
  SimDetectorsOptions detectors;
  // Fault injection: exposures whose index is in [drop_from, drop_to) never arrive (kTimeout).
  std::int64_t drop_from = -1, drop_to = -1;
  double skew_ms = 0;  // added to the second view's timestamp
  // A host that stalls: acquiring exposures in [stall_from, stall_to) takes stall_ms longer
  // than the frame does (real clock only), so those cycles overrun their period.
  std::int64_t stall_from = -1, stall_to = -1;
  double stall_ms = 0;
};

// Faults of the simulated chest marker (times in seconds on the room's clock; negative: none):
// a marker that freezes (repeats its last reading), a stream that stops, a cough (the marker
// rises by cough_mm over cough_s, the target does not follow the model), and a marker that
// slides on the skin (the surrogate drifts from the target at slide_mm_per_s).
struct SimSurrogateFaults {
  double freeze_from_s = -1;
  double stop_from_s = -1;
  double cough_at_s = -1, cough_s = 0.6, cough_mm = 8;
  double slide_from_s = -1, slide_mm_per_s = 0;
};

// One session's simulated room: its patient, set-up error and motion, its couch and what moves
// it, its detectors. Made for one session, owned by it, and destroyed after every device the
// session made from it.
class RoomSimulation {
 public:
  virtual ~RoomSimulation() = default;
  // The room's detectors (called once; the session opens and closes them).
  virtual Result<std::unique_ptr<drivers::FrameSource>> make_detectors() = 0;
  // What moves the room's couch: the virtual couch in process, or with the session's `hil` the
  // couch behind its protocol (the Modbus server, or the robot on a CAN link) commanded through
  // the real driver and clocked by the room.
  virtual Result<drivers::ActuatorSpec> couch_actuator() = 0;
  // The protocol driver of hardware in the loop (Modbus or CAN); null without `hil`.
  virtual const drivers::Actuator* protocol_driver() const = 0;
  // The simulated patient's chest marker read in process (surrogate.source sim).
  virtual std::unique_ptr<drivers::SurrogateSource> chest_marker() = 0;
  // The same marker served by the tracker's twin over OpenIGTLink on a loopback port of its own
  // (surrogate.source igtl in a simulation): the port.
  virtual Result<int> serve_chest_marker() = 0;
  // The room's truth, for the loop's statistics.
  virtual const loop::SimulatedTruth* truth() const = 0;
};

class RoomSimulator {
 public:
  virtual ~RoomSimulator() = default;
  // The simulated room of one session of `scene` (options.devices kScene with a device actuator:
  // the couch is another process's, seen through the scene's sim.couch_link). `scene` and `pool`
  // outlive what is made; what it needs of `options` is copied.
  virtual Result<std::unique_ptr<RoomSimulation>> make_room(const PreparedScene& scene,
                                                            const LoopSessionOptions& options,
                                                            tracking::ThreadPool* pool) const = 0;
  // The checks before a run with simulated detectors (preflight.hpp): the simulated frames'
  // light fields, and the served couch's room link.
  virtual void preflight(const PreparedScene& scene, const LoopSessionOptions& options,
                         PreflightReport* report) const = 0;
};

}  // namespace lftrack::session
