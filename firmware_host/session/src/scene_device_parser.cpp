// The scene's devices: detectors[i].frames (where frames come from, with the device's settings),
// detectors[i].calibration, and the device half of `actuator` (modbus, can). Every value is
// checked here, at load, with file:line:col; the drivers' factory checks again what it builds.

#include <linux/can.h>

#include "scene_yaml.hpp"

namespace lftrack::session {

namespace {

fs::path resolve(const fs::path& base_dir, const std::string& file) {
  const fs::path path(file);
  return path.is_absolute() ? path : base_dir / path;
}

}  // namespace

Status SceneParser::parse_frames(const YAML::Node& n, const std::string& what, DetectorFramesSpec* f) const {
  if (n.IsScalar()) {  // the short form: `frames: sim`, `frames: replay` (lftrack replay --sequence)
    LFTRACK_RETURN_IF_ERROR(one_of(n, what, {"sim", "v4l2", "gige", "replay"}, &f->kind));
    if (f->kind == "v4l2" || f->kind == "gige")
      return error(n, what + ": " + f->kind + " needs its device: frames: {type: " + f->kind +
                          (f->kind == "v4l2" ? ", device: /dev/v4l/by-path/...}" : ", camera: ADDRESS-OR-SERIAL}"));
    return {};
  }
  if (!n.IsMap()) return error(n, what + " must be a kind (sim, replay) or a mapping with a type");
  YAML::Node node;
  LFTRACK_RETURN_IF_ERROR(need(n, "type", what, &node));
  LFTRACK_RETURN_IF_ERROR(one_of(node, what + ".type", {"sim", "v4l2", "gige", "replay"}, &f->kind));
  long buffers = 4;
  if (f->kind == "sim") return check_keys(n, what, {"type"});
  if (f->kind == "replay") {
    LFTRACK_RETURN_IF_ERROR(check_keys(n, what, {"type", "sequence"}));
    LFTRACK_RETURN_IF_ERROR(need(n, "sequence", what, &node));
    std::string sequence;
    LFTRACK_RETURN_IF_ERROR(text(node, what + ".sequence", &sequence));
    f->sequence = resolve(folder_of(node), sequence).lexically_normal().string();
    return {};
  }
  if (f->kind == "v4l2") {
    LFTRACK_RETURN_IF_ERROR(check_keys(n, what, {"type", "device", "buffers", "trigger_control", "trigger_value"}));
    LFTRACK_RETURN_IF_ERROR(need(n, "device", what, &node));
    LFTRACK_RETURN_IF_ERROR(text(node, what + ".device", &f->device));
    if (f->device.front() != '/')
      return error(node, what + ".device must be an absolute path such as /dev/v4l/by-path/... (a stable link) or "
                                "/dev/video0");
    if (n["buffers"]) LFTRACK_RETURN_IF_ERROR(integer(n["buffers"], what + ".buffers", 2, 32, &buffers));
    if (n["trigger_control"]) {
      long id = 0;
      LFTRACK_RETURN_IF_ERROR(integer(n["trigger_control"], what + ".trigger_control", 0, 0xFFFFFFFFL, &id));
      f->trigger_control_id = static_cast<std::uint32_t>(id);
    }
    if (n["trigger_value"]) {
      long value = 1;
      LFTRACK_RETURN_IF_ERROR(
          integer(n["trigger_value"], what + ".trigger_value", -2147483648L, 2147483647L, &value));
      f->trigger_value = static_cast<std::int32_t>(value);
    }
  } else {  // gige
    LFTRACK_RETURN_IF_ERROR(
        check_keys(n, what, {"type", "camera", "buffers", "packet_timeout_ms", "id", "exposure_clock"}));
    LFTRACK_RETURN_IF_ERROR(need(n, "camera", what, &node));
    LFTRACK_RETURN_IF_ERROR(text(node, what + ".camera", &f->device));
    if (n["id"]) LFTRACK_RETURN_IF_ERROR(text(n["id"], what + ".id", &f->id));
    if (n["buffers"]) LFTRACK_RETURN_IF_ERROR(integer(n["buffers"], what + ".buffers", 2, 64, &buffers));
    if (n["packet_timeout_ms"]) {
      LFTRACK_RETURN_IF_ERROR(positive(n["packet_timeout_ms"], what + ".packet_timeout_ms", &f->packet_timeout_ms));
      if (f->packet_timeout_ms > 1000) return error(n["packet_timeout_ms"], what + ".packet_timeout_ms: at most 1000");
    }
    if (n["exposure_clock"]) {
      std::string clock;
      LFTRACK_RETURN_IF_ERROR(
          one_of(n["exposure_clock"], what + ".exposure_clock", {"device", "arrival"}, &clock));
      f->exposure_by_arrival = clock == "arrival";
    }
  }
  f->buffers = static_cast<int>(buffers);
  return {};
}

Status SceneParser::parse_detector_calibration(const YAML::Node& n, const std::string& what,
                                               std::string* file) const {
  std::string name;
  LFTRACK_RETURN_IF_ERROR(text(n, what, &name));
  if (name == "simulator") {  // the caller marks the detector (simulator_calibration)
    file->clear();
    return {};
  }
  const fs::path path = resolve(folder_of(n), name);
  std::error_code ec;
  if (!fs::is_regular_file(path, ec))
    return error(n, what + ": no detector calibration file " + path.string() +
                        " (make one with `lftrack calibrate detector --dark DIR --flood DIR --out FILE`)");
  *file = path.string();
  return {};
}

Status SceneParser::parse_modbus(const YAML::Node& n, drivers::ModbusCouchOptions* m) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "actuator.modbus", {"tcp", "rtu", "unit_id", "response_timeout_ms"}));
  if (n["tcp"] && n["rtu"]) return error(n, "actuator.modbus names both tcp and rtu; a couch has one link");
  if (const YAML::Node tcp = n["tcp"]) {
    LFTRACK_RETURN_IF_ERROR(check_keys(tcp, "actuator.modbus.tcp", {"host", "port"}));
    YAML::Node node;
    m->transport = drivers::ModbusCouchOptions::Transport::kTcp;
    LFTRACK_RETURN_IF_ERROR(need(tcp, "host", "actuator.modbus.tcp", &node));
    LFTRACK_RETURN_IF_ERROR(text(node, "actuator.modbus.tcp.host", &m->host));
    long port = 502;
    if (tcp["port"]) LFTRACK_RETURN_IF_ERROR(integer(tcp["port"], "actuator.modbus.tcp.port", 1, 65535, &port));
    m->port = static_cast<int>(port);
  } else if (const YAML::Node rtu = n["rtu"]) {
    LFTRACK_RETURN_IF_ERROR(
        check_keys(rtu, "actuator.modbus.rtu", {"device", "baud", "parity", "data_bits", "stop_bits"}));
    YAML::Node node;
    m->transport = drivers::ModbusCouchOptions::Transport::kRtu;
    LFTRACK_RETURN_IF_ERROR(need(rtu, "device", "actuator.modbus.rtu", &node));
    LFTRACK_RETURN_IF_ERROR(text(node, "actuator.modbus.rtu.device", &m->serial_device));
    long baud = 115200, data_bits = 8, stop_bits = 1;
    if (rtu["baud"]) {
      LFTRACK_RETURN_IF_ERROR(integer(rtu["baud"], "actuator.modbus.rtu.baud", 1200, 4000000, &baud));
      static const long kRates[] = {1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600};
      bool known = false;
      for (long r : kRates) known = known || r == baud;
      if (!known) return error(rtu["baud"], "actuator.modbus.rtu.baud must be a standard rate (1200 ... 921600)");
    }
    if (rtu["parity"]) {
      std::string parity;
      LFTRACK_RETURN_IF_ERROR(one_of(rtu["parity"], "actuator.modbus.rtu.parity", {"none", "even", "odd"}, &parity));
      m->parity = parity == "none" ? 'N' : parity == "even" ? 'E' : 'O';
    }
    if (rtu["data_bits"])
      LFTRACK_RETURN_IF_ERROR(integer(rtu["data_bits"], "actuator.modbus.rtu.data_bits", 7, 8, &data_bits));
    if (rtu["stop_bits"])
      LFTRACK_RETURN_IF_ERROR(integer(rtu["stop_bits"], "actuator.modbus.rtu.stop_bits", 1, 2, &stop_bits));
    m->baud = static_cast<int>(baud);
    m->data_bits = static_cast<int>(data_bits);
    m->stop_bits = static_cast<int>(stop_bits);
  } else {
    return error(n, "actuator.modbus needs its link: tcp: {host, port} or rtu: {device, baud, parity}");
  }
  long unit = 1;
  if (n["unit_id"]) LFTRACK_RETURN_IF_ERROR(integer(n["unit_id"], "actuator.modbus.unit_id", 1, 247, &unit));
  m->unit_id = static_cast<int>(unit);
  if (const YAML::Node t = n["response_timeout_ms"]) {
    double ms = 0;
    LFTRACK_RETURN_IF_ERROR(positive(t, "actuator.modbus.response_timeout_ms", &ms));
    if (ms > 10000) return error(t, "actuator.modbus.response_timeout_ms: at most 10000");
    m->response_timeout_s = 1e-3 * ms;
  }
  return {};
}

Status SceneParser::parse_can(const YAML::Node& n, drivers::CanRobotOptions* c) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "actuator.can", {"interface", "bridge", "node_id", "heartbeat_timeout_ms"}));
  if (n["interface"] && n["bridge"]) return error(n, "actuator.can names both interface and bridge; use one");
  if (n["interface"]) {
    LFTRACK_RETURN_IF_ERROR(text(n["interface"], "actuator.can.interface", &c->interface));
    if (c->interface.size() >= 16) return error(n["interface"], "actuator.can.interface: at most 15 characters");
  } else if (n["bridge"]) {
    std::string bridge;
    LFTRACK_RETURN_IF_ERROR(text(n["bridge"], "actuator.can.bridge", &bridge));
    c->bridge_path = resolve(folder_of(n["bridge"]), bridge).lexically_normal().string();
    if (c->bridge_path.size() >= 108)
      return error(n["bridge"], "actuator.can.bridge: a socket path is at most 107 bytes; got " + c->bridge_path);
  } else {
    return error(n, "actuator.can needs an interface (e.g. can0) or a bridge (a socket path)");
  }
  long node = 1;
  if (n["node_id"]) LFTRACK_RETURN_IF_ERROR(integer(n["node_id"], "actuator.can.node_id", 1, 15, &node));
  c->node_id = static_cast<int>(node);
  if (const YAML::Node t = n["heartbeat_timeout_ms"]) {
    double ms = 0;
    LFTRACK_RETURN_IF_ERROR(positive(t, "actuator.can.heartbeat_timeout_ms", &ms));
    if (ms > 10000) return error(t, "actuator.can.heartbeat_timeout_ms: at most 10000");
    c->heartbeat_timeout_s = 1e-3 * ms;
  }
  return {};
}

Status SceneParser::check_devices(const YAML::Node& root, const Scene& scene) const {
  const YAML::Node detectors = root["detectors"];
  for (std::size_t i = 1; i < scene.detectors.size(); ++i) {
    const DetectorFramesSpec &first = scene.detectors[0].frames, &f = scene.detectors[i].frames;
    const YAML::Node at = detectors[i]["frames"] ? detectors[i]["frames"] : detectors[i];
    if (f.kind != first.kind)
      return error(at, "detectors take their frames from '" + first.kind + "' and '" + f.kind +
                           "': a pair comes from one source, so every detector names the same kind");
    if (f.kind == "replay" && f.sequence != first.sequence)
      return error(at, "replayed detectors name two sequences (" + first.sequence + ", " + f.sequence +
                           "): a pair comes from one archived sequence");
    if ((f.kind == "v4l2" || f.kind == "gige") && f.device == first.device)
      return error(at, "two detectors name the same device " + f.device);
  }
  if (scene.actuator.type == "virtual" && !scene.detectors.empty() && scene.detectors[0].frames.kind != "sim")
    return error(root["actuator"], "actuator.type virtual is the simulator's couch: it moves a simulated patient, so "
                                   "the detectors must be simulated (frames: sim)");
  const bool real_actuator = scene.actuator.type == "modbus" || scene.actuator.type == "can";
  if (real_actuator && !scene.detectors.empty() && scene.detectors[0].frames.kind == "replay")
    return error(root["actuator"], "archived frames cannot move a patient: detectors with frames from replay show "
                                   "a patient who is no longer there, so the " + scene.actuator.type +
                                   " actuator must not be driven by them (actuator.type none tracks and reports them; "
                                   "lftrack replay --sequence replays any archive)");
  // A served couch's room link: written by that couch or robot, read by simulated detectors. A
  // link that nothing in the scene would write or read is a mistake in the scene.
  if (!scene.sim.couch_link.empty()) {
    const YAML::Node at = root["sim"]["couch_link"];
    if (!real_actuator)
      return error(at, "sim.couch_link is a served couch's or robot's room link, and actuator.type " +
                           scene.actuator.type + " is neither: nothing would write it (a modbus or can actuator "
                           "served by lftrack serve couch|robot --room FILE does)");
    if (!scene.detectors.empty() && scene.detectors[0].frames.kind != "sim")
      return error(at, "sim.couch_link is read by simulated detectors, and these take their frames from " +
                           scene.detectors[0].frames.kind +
                           " (a detector server reads the link itself: lftrack serve detectors --room FILE)");
  }
  return {};
}

}  // namespace lftrack::session
