#pragma once
// From a scene's device sections to the drivers' specs (device_factory.hpp), and back to words
// and YAML. The simulator's devices (frames: sim, actuator: virtual) are made by LoopSession,
// which owns the simulated room they share; every other kind is filled in here.

#include <string>

#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/session/scene.hpp"

namespace lftrack::session {

// "v4l2 /dev/v4l/by-path/...", "gige 127.0.0.1", "replay DIR", "sim".
std::string describe_frames(const DetectorFramesSpec& frames);
// The flow-style YAML a scene writes for it: "sim", "{type: v4l2, device: /dev/video0, buffers: 4}".
std::string frames_yaml(const DetectorFramesSpec& frames);
// "modbus tcp 127.0.0.1:1502 unit 1", "can bridge /run/robot.sock node 1", "virtual", "none".
std::string describe_actuator(const ActuatorSpec& actuator);

// The device id (serial number) `lftrack serve detectors` gives the camera it serves as detector
// `detector_name`, the simulator's twin of that detector: "LFTRACK-<name>" where that fits the 15
// characters a GigE Vision serial number holds, else "LFTRACK-" + the name's first two
// characters + five hex digits of its hash (names that share a prefix get different ids).
std::string served_twin_id(const std::string& detector_name);

// What kind of device a scene names, asked by the session and the start-up checks, so that
// device names are spelled here and in the parser only.
bool frames_are_simulated(const Scene& scene);              // detectors' frames: sim
bool frames_from_device(const DetectorFramesSpec& frames);  // v4l2 or gige: a detector of its own
bool actuator_is_device(const Scene& scene);                // modbus or can
bool actuator_is_virtual(const Scene& scene);               // the simulator's couch
bool actuator_moves(const Scene& scene);                    // anything but none

// The frame source of a scene whose detectors are devices (v4l2, gige, replay). Fails for sim.
Result<drivers::FrameSourceSpec> device_frame_source_spec(const Scene& scene);
// The actuator of a scene with a modbus or can actuator. Fails for none and virtual.
Result<drivers::ActuatorSpec> device_actuator_spec(const Scene& scene);

}  // namespace lftrack::session
