#include "lftrack/session/scene_devices.hpp"

#include <cstdint>
#include <cstdio>
#include <sstream>

namespace lftrack::session {

std::string describe_frames(const DetectorFramesSpec& f) {
  if (f.kind == "v4l2" || f.kind == "gige") return f.kind + " " + f.device;
  if (f.kind == "replay") return f.sequence.empty() ? std::string("replay (lftrack replay --sequence)") : "replay " + f.sequence;
  return f.kind;
}

std::string frames_yaml(const DetectorFramesSpec& f) {
  std::ostringstream y;
  if (f.kind == "v4l2") {
    y << "{type: v4l2, device: \"" << f.device << "\", buffers: " << f.buffers;
    if (f.trigger_control_id != 0)
      y << ", trigger_control: " << f.trigger_control_id << ", trigger_value: " << f.trigger_value;
    y << "}";
  } else if (f.kind == "gige") {
    y << "{type: gige, camera: \"" << f.device << "\", buffers: " << f.buffers
      << ", packet_timeout_ms: " << f.packet_timeout_ms;
    if (!f.id.empty()) y << ", id: \"" << f.id << "\"";
    if (f.exposure_by_arrival) y << ", exposure_clock: arrival";
    y << "}";
  } else if (f.kind == "replay" && !f.sequence.empty()) {
    y << "{type: replay, sequence: \"" << f.sequence << "\"}";
  } else {
    y << f.kind;
  }
  return y.str();
}

std::string describe_actuator(const ActuatorSpec& a) {
  std::ostringstream s;
  if (a.type == "modbus") {
    const drivers::ModbusCouchOptions& m = a.modbus;
    if (m.transport == drivers::ModbusCouchOptions::Transport::kTcp)
      s << "modbus tcp " << m.host << ":" << m.port;
    else
      s << "modbus rtu " << m.serial_device << " " << m.baud << " baud";
    s << " unit " << m.unit_id;
  } else if (a.type == "can") {
    if (!a.can.bridge_path.empty())
      s << "can bridge " << a.can.bridge_path;
    else
      s << "can " << a.can.interface;
    s << " node " << a.can.node_id;
  } else {
    s << a.type;
  }
  return s.str();
}

std::string served_twin_id(const std::string& detector_name) {
  const std::string whole = "LFTRACK-" + detector_name;
  if (whole.size() <= 15) return whole;
  // Cut to 15 characters, two names sharing their first 7 would get one id and a swap of their
  // cameras would pass the identity check: the name's first two characters, then five hex digits
  // of its FNV-1a hash (serve detectors refuses the rare scene whose ids still coincide).
  std::uint32_t hash = 2166136261u;
  for (unsigned char c : detector_name) hash = (hash ^ c) * 16777619u;
  char digits[8];
  std::snprintf(digits, sizeof digits, "%05x", hash & 0xFFFFFu);
  return "LFTRACK-" + detector_name.substr(0, 2) + digits;
}

bool frames_are_simulated(const Scene& scene) {
  return !scene.detectors.empty() && scene.detectors[0].frames.kind == "sim";
}
bool frames_from_device(const DetectorFramesSpec& frames) { return frames.kind == "v4l2" || frames.kind == "gige"; }
bool actuator_is_device(const Scene& scene) { return scene.actuator.type == "modbus" || scene.actuator.type == "can"; }
bool actuator_is_virtual(const Scene& scene) { return scene.actuator.type == "virtual"; }
bool actuator_moves(const Scene& scene) { return scene.actuator.type != "none"; }

Result<drivers::FrameSourceSpec> device_frame_source_spec(const Scene& scene) {
  if (scene.detectors.empty()) return invalid_argument(scene.name + ": the scene has no detectors");
  const DetectorFramesSpec& first = scene.detectors[0].frames;
  std::vector<drivers::DetectorShape> shapes;
  for (const DetectorSpec& d : scene.detectors) shapes.push_back({d.view.name, d.view.rows, d.view.cols});
  if (first.kind == "replay") {
    if (first.sequence.empty())
      return invalid_argument(scene.name + ": replayed detectors name no sequence (frames: {type: replay, sequence: DIR})");
    drivers::ReplaySourceSpec spec;
    spec.sequence = first.sequence;
    spec.detectors = shapes;
    spec.options.realtime = true;
    return drivers::FrameSourceSpec(std::move(spec));
  }
  if (first.kind == "v4l2") {
    drivers::V4l2SourceSpec spec;
    for (const DetectorSpec& d : scene.detectors) {
      drivers::V4l2DetectorOptions o;
      o.device = d.frames.device;
      o.rows = d.view.rows;
      o.cols = d.view.cols;
      o.buffers = d.frames.buffers;
      o.trigger_control_id = d.frames.trigger_control_id;
      o.trigger_value = d.frames.trigger_value;
      spec.detectors.push_back(o);
    }
    return drivers::FrameSourceSpec(std::move(spec));
  }
  if (first.kind == "gige") {
    drivers::GigeSourceSpec spec;
    for (const DetectorSpec& d : scene.detectors) {
      drivers::GigeDetectorOptions o;
      o.camera = d.frames.device;
      o.rows = d.view.rows;
      o.cols = d.view.cols;
      o.buffers = d.frames.buffers;
      o.trigger = drivers::GigeTrigger::kSoftware;  // the loop exposes at each cycle's start
      o.packet_timeout_ms = d.frames.packet_timeout_ms;
      o.exposure_clock =
          d.frames.exposure_by_arrival ? drivers::ExposureClock::kArrival : drivers::ExposureClock::kDevice;
      spec.detectors.push_back(o);
    }
    return drivers::FrameSourceSpec(std::move(spec));
  }
  return invalid_argument(scene.name + ": detectors with frames from '" + first.kind +
                          "' are not devices the drivers' factory makes");
}

Result<drivers::ActuatorSpec> device_actuator_spec(const Scene& scene) {
  if (scene.actuator.type == "modbus") return drivers::ActuatorSpec(drivers::ModbusActuatorSpec{scene.actuator.modbus});
  if (scene.actuator.type == "can") return drivers::ActuatorSpec(drivers::CanActuatorSpec{scene.actuator.can, -1});
  return invalid_argument(scene.name + ": actuator '" + scene.actuator.type + "' is not a device the drivers' factory makes");
}

}  // namespace lftrack::session
