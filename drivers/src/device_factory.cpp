#include "lftrack/drivers/device_factory.hpp"

#include <unistd.h>

#include "lftrack/drivers/frame_sequence.hpp"
#include "lftrack/drivers/recorded_actuator.hpp"

namespace lftrack::drivers {

namespace {

template <class... F>
struct Overloaded : F... {
  using F::operator()...;
};
template <class... F>
Overloaded(F...) -> Overloaded<F...>;

Result<std::unique_ptr<FrameSource>> make_v4l2(V4l2SourceSpec spec) {
  if (spec.detectors.empty()) return invalid_argument("v4l2 frame source: no detectors");
  if (!(spec.max_skew_ms > 0) || spec.max_skew_ms > 1000)
    return invalid_argument("v4l2 frame source: max_skew_ms must be in (0, 1000]");
  std::vector<std::unique_ptr<V4l2Detector>> detectors;
  for (std::size_t i = 0; i < spec.detectors.size(); ++i) {
    const V4l2DetectorOptions& d = spec.detectors[i];
    const std::string which = "v4l2 detector " + std::to_string(i + 1);
    if (d.device.empty()) return invalid_argument(which + ": no device path (e.g. /dev/v4l/by-path/...)");
    if (d.rows <= 0 || d.cols <= 0 || d.rows > 16384 || d.cols > 16384)
      return invalid_argument(which + " (" + d.device + "): rows and cols must be 1 to 16384");
    if (d.buffers < 2 || d.buffers > 32)
      return invalid_argument(which + " (" + d.device + "): buffers must be 2 to 32");
    detectors.push_back(std::make_unique<V4l2Detector>(d));
  }
  return std::unique_ptr<FrameSource>(new V4l2FrameSource(std::move(detectors), spec.max_skew_ms));
}

Result<std::unique_ptr<FrameSource>> make_simulated(const SimulatedSourceSpec& spec) {
  if (!spec.make) return invalid_argument(spec.description + ": no simulator to make them");
  auto source = spec.make();
  if (source.ok() && *source == nullptr) return internal_error(spec.description + ": the simulator made nothing");
  return source;
}

Result<std::unique_ptr<Actuator>> make_virtual(const VirtualActuatorSpec& spec) {
  if (!spec.make) return invalid_argument("virtual actuator: no simulator to make it");
  auto actuator = spec.make();
  if (actuator.ok() && *actuator == nullptr) return internal_error("virtual actuator: the simulator made nothing");
  return actuator;
}

Result<std::unique_ptr<FrameSource>> make_gige(GigeSourceSpec spec) {
  if (spec.detectors.empty()) return invalid_argument("gige frame source: no detectors");
  if (!(spec.max_skew_ms > 0) || spec.max_skew_ms > 1000)
    return invalid_argument("gige frame source: max_skew_ms must be in (0, 1000]");
  for (std::size_t i = 0; i < spec.detectors.size(); ++i) {
    LFTRACK_RETURN_IF_ERROR(validate_gige_options(spec.detectors[i]));
    for (std::size_t j = 0; j < i; ++j)
      if (spec.detectors[j].camera == spec.detectors[i].camera)
        return invalid_argument("gige frame source: two detectors name the camera " + spec.detectors[i].camera);
  }
  return std::unique_ptr<FrameSource>(new GigeFrameSource(std::move(spec.detectors), spec.max_skew_ms));
}

Result<std::unique_ptr<FrameSource>> make_replay(ReplaySourceSpec spec) {
  if (spec.detectors.empty()) return invalid_argument("replay frame source: no detectors");
  auto sequence = read_frame_sequence(spec.sequence);
  if (!sequence.ok()) return sequence.status();
  return std::unique_ptr<FrameSource>(
      new ReplayFrameSource(std::move(sequence).value(), std::move(spec.detectors), spec.options));
}

Result<std::unique_ptr<Actuator>> make_modbus(const ModbusActuatorSpec& spec) {
  const ModbusCouchOptions& o = spec.options;
  const bool tcp = o.transport == ModbusCouchOptions::Transport::kTcp;
  if (tcp && (o.host.empty() || o.port <= 0 || o.port > 65535))
    return invalid_argument("modbus couch: TCP needs a host and a port from 1 to 65535");
  if (!tcp && o.serial_device.empty()) return invalid_argument("modbus couch: RTU needs a serial device");
  if (o.unit_id < 0 || o.unit_id > 247) return invalid_argument("modbus couch: unit id must be 0 to 247");
  if (!(o.response_timeout_s > 0) || o.response_timeout_s > 10)
    return invalid_argument("modbus couch: response timeout must be in (0, 10] s");
  return std::unique_ptr<Actuator>(new ModbusCouch(o));
}

Result<std::unique_ptr<Actuator>> make_can(const CanActuatorSpec& spec) {
  if (spec.options.node_id < 1 || spec.options.node_id > 15) {
    if (spec.link_fd >= 0) ::close(spec.link_fd);
    return invalid_argument("can robot: node id must be 1 to 15");
  }
  if (spec.link_fd >= 0) return std::unique_ptr<Actuator>(new CanRobot(spec.options, spec.link_fd));
  if (spec.options.interface.empty() && spec.options.bridge_path.empty())
    return invalid_argument("can robot: no interface (e.g. can0), no bridge socket and no link");
  if (!spec.options.bridge_path.empty() &&
      (!(spec.options.reconnect_interval_s > 0) || spec.options.reconnect_interval_s > 60))
    return invalid_argument("can robot: reconnect interval must be in (0, 60] s");
  if (!(spec.options.heartbeat_timeout_s > 0) || spec.options.heartbeat_timeout_s > 10)
    return invalid_argument("can robot: heartbeat timeout must be in (0, 10] s");
  return std::unique_ptr<Actuator>(new CanRobot(spec.options));
}

Result<std::unique_ptr<Actuator>> make_recorded(const RecordedActuatorSpec& spec) {
  if (spec.frames == nullptr) return invalid_argument("recorded couch: needs the replayed sequence");
  if (!spec.frames->sequence().has_actuator)
    return failed_precondition("recorded couch: the sequence recorded no actuator read-backs");
  return std::unique_ptr<Actuator>(new RecordedActuator(spec.frames));
}

}  // namespace

const char* kind_name(const FrameSourceSpec& spec) {
  return std::visit(Overloaded{[](const SimulatedSourceSpec&) { return "sim"; },
                               [](const V4l2SourceSpec&) { return "v4l2"; },
                               [](const GigeSourceSpec&) { return "gige"; },
                               [](const ReplaySourceSpec&) { return "replay"; }},
                    spec);
}

const char* kind_name(const ActuatorSpec& spec) {
  return std::visit(Overloaded{[](const VirtualActuatorSpec&) { return "virtual"; },
                               [](const ModbusActuatorSpec&) { return "modbus"; },
                               [](const CanActuatorSpec&) { return "can"; },
                               [](const RecordedActuatorSpec&) { return "recorded"; }},
                    spec);
}

Result<std::unique_ptr<FrameSource>> make_frame_source(FrameSourceSpec spec) {
  return std::visit(Overloaded{[](SimulatedSourceSpec& s) { return make_simulated(s); },
                               [](V4l2SourceSpec& s) { return make_v4l2(std::move(s)); },
                               [](GigeSourceSpec& s) { return make_gige(std::move(s)); },
                               [](ReplaySourceSpec& s) { return make_replay(std::move(s)); }},
                    spec);
}

Result<std::unique_ptr<Actuator>> make_actuator(ActuatorSpec spec) {
  return std::visit(Overloaded{[](const VirtualActuatorSpec& s) { return make_virtual(s); },
                               [](const ModbusActuatorSpec& s) { return make_modbus(s); },
                               [](const CanActuatorSpec& s) { return make_can(s); },
                               [](const RecordedActuatorSpec& s) { return make_recorded(s); }},
                    spec);
}

}  // namespace lftrack::drivers
