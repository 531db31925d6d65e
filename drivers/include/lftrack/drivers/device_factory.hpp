#pragma once
// One factory for every device the drivers implement. A spec says what a device is, with its
// settings; make_frame_source and make_actuator build it, unopened (the loop opens devices
// outside the cycle). The spec's type names the kind, so the code that assembles a run holds no
// chain of if/else over device names: it fills a spec (from a scene, a command line) and calls
// the factory. Simulated devices belong to the simulator (sim/ builds on drivers/): their spec
// carries the simulator's own maker, so they come through the same call.
//
// Checks that need no hardware are made here, with messages that name the device: a V4L2
// detector without a device path or a size, a GigE camera with bad options
// (validate_gige_options), a replayed sequence that cannot be read, a Modbus
// couch without a host or serial device, a CAN robot with neither an interface nor a link.

#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/drivers/can_robot.hpp"
#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/drivers/gige_detector.hpp"
#include "lftrack/drivers/modbus_couch.hpp"
#include "lftrack/drivers/replay_frame_source.hpp"
#include "lftrack/drivers/v4l2_detector.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::drivers {

// Frame sources.
// The simulator's detectors (or any source made elsewhere): `make` builds it; `description`
// names it in messages.
struct SimulatedSourceSpec {
  std::function<Result<std::unique_ptr<FrameSource>>()> make;
  std::string description = "simulated detectors";
};
struct V4l2SourceSpec {
  std::vector<V4l2DetectorOptions> detectors;  // one per detector, in the scene's order
  double max_skew_ms = 20;                     // a pair's two exposures at most this far apart
};
struct GigeSourceSpec {
  std::vector<GigeDetectorOptions> detectors;  // one camera per detector, in the scene's order
  double max_skew_ms = 20;                     // a pair's two frames at most this far apart
};
struct ReplaySourceSpec {
  std::filesystem::path sequence;       // an archived sequence's folder (frame_sequence.hpp)
  std::vector<DetectorShape> detectors;  // the scene's, in its order
  ReplayOptions options;
};
using FrameSourceSpec = std::variant<SimulatedSourceSpec, V4l2SourceSpec, GigeSourceSpec, ReplaySourceSpec>;

// Actuators.
// The simulator's couch or robot (made by the simulator, as SimulatedSourceSpec).
struct VirtualActuatorSpec {
  std::function<Result<std::unique_ptr<Actuator>>()> make;
};
struct ModbusActuatorSpec {
  ModbusCouchOptions options;
};
struct CanActuatorSpec {
  CanRobotOptions options;
  // An open, connected link carrying struct can_frame records (a bridge process's socket, a
  // socket pair to the virtual robot); the actuator takes it over. -1: options.bridge_path if
  // set, else options.interface.
  int link_fd = -1;
};
// The couch read-backs recorded beside an archived sequence, in step with its frames.
struct RecordedActuatorSpec {
  const ReplayFrameSource* frames = nullptr;
};
using ActuatorSpec = std::variant<VirtualActuatorSpec, ModbusActuatorSpec, CanActuatorSpec, RecordedActuatorSpec>;

// The kind's name, as scenes and messages say it: "sim", "v4l2", "gige", "replay", "virtual", "modbus",
// "can", "recorded".
const char* kind_name(const FrameSourceSpec& spec);
const char* kind_name(const ActuatorSpec& spec);

Result<std::unique_ptr<FrameSource>> make_frame_source(FrameSourceSpec spec);
Result<std::unique_ptr<Actuator>> make_actuator(ActuatorSpec spec);

}  // namespace lftrack::drivers
