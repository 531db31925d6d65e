// `lftrack serve couch|robot`: a simulated device as a process of its own, speaking the real
// protocol, so hardware in the loop runs across processes (and, for Modbus TCP, across
// machines). `serve couch` is the virtual couch behind a Modbus TCP server; `serve robot` the
// virtual robot behind a CAN bridge socket. With --room FILE the device publishes where it has
// moved the patient, for simulated detectors in other processes (sim/room_link.hpp).
//
// Faults: `--fault KIND[:COUNT][@SECONDS]` (repeatable) injects at a time after start;
// `--control PATH` takes datagrams `fault KIND[:COUNT]` and `status` while it runs (mode 0600).
// The first line on standard output says where the device listens; the last, what it served.

#include <arpa/inet.h>

#include <cstdio>
#include <nlohmann/json.hpp>

#include "lftrack/sim/can_bridge_server.hpp"
#include "lftrack/sim/modbus_couch_server.hpp"
#include "lftrack/sim/null_modem.hpp"
#include "lftrack/sim/served_couch.hpp"
#include "lftrack/watch/listen_address.hpp"
#include "serve_common.hpp"

namespace lftrack::cli {

using session::load_scene;

using watch::ListenAddress;
using watch::reachable_warning;
namespace {

using namespace serve;

Result<drivers::ActuatorDynamics> couch_dynamics(const ServeOptions& o) {
  if (!o.scene_given) return drivers::ActuatorDynamics{};
  auto scene = load_scene(o.scene.scene);
  if (!scene.ok()) return scene.status();
  return scene->actuator.dynamics;
}

std::map<std::string, int> couch_fault_kinds() {
  using F = sim::CouchServerFault;
  return {{"no-reply", int(F::kNoReply)}, {"exception4", int(F::kException4)},
          {"busy", int(F::kException6)},   {"wrong-unit", int(F::kWrongUnit)},
          {"drop", int(F::kDropConnection)}, {"mismatch", int(F::kReadbackMismatch)},
          {"late", int(F::kLateReply)}};
}

std::map<std::string, int> robot_fault_kinds() {
  using R = sim::RobotFault;
  return {
      {"bus-off", int(R::kBusOff)},           {"error-passive", int(R::kErrorPassive)},
      {"error-active", int(R::kErrorActive)}, {"controller-restarted", int(R::kControllerRestarted)},
      {"robot-restart", int(R::kRobotRestart)}, {"stop-heartbeat", int(R::kStopHeartbeat)},
      {"resume-heartbeat", int(R::kResumeHeartbeat)}, {"error-flood", int(R::kErrorFlood)},
      {"unplug", -1}};
}

Status serve_couch(const ServeOptions& o) {
  if (auto checked = check_serve_options(o, couch_fault_kinds()); !checked.ok()) return checked.status();
  // tcp:ADDRESS:PORT (PORT 0: any free port), rtu:DEVICE (a serial port), or rtu:pty (a
  // null-modem pair of pseudo-terminals made here: the server takes one end, and the first line
  // names the other for the client).
  sim::ModbusCouchServerOptions server;
  std::unique_ptr<sim::NullModem> serial_line;
  std::string client_end;
  if (o.endpoint.rfind("rtu:", 0) == 0) {
    const std::string device = o.endpoint.substr(4);
    if (device == "pty") {
      serial_line = std::make_unique<sim::NullModem>();
      if (!serial_line->ok()) return io_error("--modbus rtu:pty: no pseudo-terminals on this host");
      server.rtu_device = serial_line->end(1);
      client_end = serial_line->end(0);
    } else if (!device.empty() && device.front() == '/') {
      server.rtu_device = device;
    } else {
      return invalid_argument("--modbus rtu:DEVICE needs a device path (e.g. rtu:/dev/ttyS1) or rtu:pty; got '" +
                              o.endpoint + "'");
    }
  } else {
    if (o.endpoint.rfind("tcp:", 0) != 0)
      return invalid_argument("--modbus must be tcp:ADDRESS:PORT (e.g. tcp:127.0.0.1:1502), rtu:DEVICE or rtu:pty; got '" +
                              o.endpoint + "'");
    const std::string address_port = o.endpoint.substr(4);
    const auto colon = address_port.rfind(':');
    char* end = nullptr;
    const long port = colon == std::string::npos ? -1 : std::strtol(address_port.c_str() + colon + 1, &end, 10);
    if (colon == std::string::npos || colon == 0 || end == address_port.c_str() + colon + 1 || *end != '\0' ||
        port < 0 || port > 65535)
      return invalid_argument("--modbus tcp:ADDRESS:PORT needs an address and a port from 0 to 65535; got '" +
                              o.endpoint + "'");
    server.address = address_port.substr(0, colon);
    server.port = static_cast<int>(port);
    in_addr parsed{};
    if (::inet_pton(AF_INET, server.address.c_str(), &parsed) != 1)
      return invalid_argument("--modbus tcp:ADDRESS:PORT: '" + server.address +
                              "' is not an IPv4 address (e.g. 127.0.0.1, or 0.0.0.0 for every interface)");
  }
  auto dynamics = couch_dynamics(o);
  if (!dynamics.ok()) return dynamics.status();
  if (o.scene_given) {  // the unit the scene's couch driver addresses (the server answers only it)
    auto scene = load_scene(o.scene.scene);
    if (!scene.ok()) return scene.status();
    if (scene->actuator.type == "modbus") server.unit_id = scene->actuator.modbus.unit_id;
  }
  auto couch = sim::ServedCouch::start(*dynamics, o.room);
  if (!couch.ok()) return couch.status();
  auto modbus = sim::ModbusCouchServer::start(couch->get(), server);
  if (!modbus.ok()) return modbus.status();
  if (server.rtu_device.empty()) {
    ListenAddress at;
    at.address = server.address;
    at.port = (*modbus)->port();
    const std::string w =
        reachable_warning(at, "the modbus couch server", "move the couch (Modbus has no authentication)");
    if (!w.empty()) spdlog::warn("{}", w);
  }
  const auto announce = [&] {
    if (server.rtu_device.empty())
      std::printf("lftrack serve couch: modbus tcp %s:%d", server.address.c_str(), (*modbus)->port());
    else
      std::printf("lftrack serve couch: modbus rtu %s",
                  serial_line ? client_end.c_str() : server.rtu_device.c_str());
    std::printf("%s%s\n", o.room.empty() ? "" : "; room link ", o.room.c_str());
  };
  using F = sim::CouchServerFault;
  const std::map<std::string, int> kinds = couch_fault_kinds();
  sim::ModbusCouchServer* s = modbus->get();
  sim::ServedCouch* c = couch->get();
  const auto describe = [&] {
    const tracking::Vector6d q = c->position();
    char line[256];
    std::snprintf(line, sizeof line,
                  "requests %lld (refused %lld), connections %lld (turned away %lld, closed idle %lld), "
                  "commands %lld, holds %lld, beam permit %s, position mm (%.3f, %.3f, %.3f)",
                  static_cast<long long>(s->requests()), static_cast<long long>(s->malformed()),
                  static_cast<long long>(s->connections()), static_cast<long long>(s->turned_away()),
                  static_cast<long long>(s->idle_closed()), static_cast<long long>(c->commands()),
                  static_cast<long long>(c->holds()), c->beam_permit() ? "on" : "off", q[0], q[1], q[2]);
    return std::string(line);
  };
  LFTRACK_RETURN_IF_ERROR(serve_until_stopped(
      o, kinds,
      [&](const Fault& f) {
        s->inject(static_cast<F>(kinds.at(f.kind)), f.count);
        return true;
      },
      describe, announce));
  if (o.json) {
    const tracking::Vector6d q = c->position();
    nlohmann::json j = {{"device", "couch"},
                        {"requests", s->requests()},
                        {"requests_refused", s->malformed()},
                        {"connections", s->connections()},
                        {"connections_turned_away", s->turned_away()},
                        {"connections_closed_idle", s->idle_closed()},
                        {"commands", c->commands()},
                        {"holds", c->holds()},
                        {"position", {q[0], q[1], q[2], q[3], q[4], q[5]}}};
    std::printf("%s\n", j.dump().c_str());
  } else {
    std::printf("served: %s\n", describe().c_str());
  }
  return {};
}

Status serve_robot(const ServeOptions& o) {
  if (auto checked = check_serve_options(o, robot_fault_kinds()); !checked.ok()) return checked.status();
  auto dynamics = couch_dynamics(o);
  if (!dynamics.ok()) return dynamics.status();
  auto device = sim::ServedCouch::start(*dynamics, o.room);
  if (!device.ok()) return device.status();
  auto bridge = sim::CanBridgeServer::start(o.endpoint, device->get());
  if (!bridge.ok()) return bridge.status();
  const auto announce = [&] {
    std::printf("lftrack serve robot: can bridge %s%s%s\n", o.endpoint.c_str(),
                o.room.empty() ? "" : "; room link ", o.room.c_str());
  };
  using R = sim::RobotFault;
  const std::map<std::string, int> kinds = robot_fault_kinds();
  sim::CanBridgeServer* b = bridge->get();
  sim::ServedCouch* c = device->get();
  const auto describe = [&] {
    const tracking::Vector6d q = c->position();
    char line[256];
    std::snprintf(line, sizeof line, "connections %lld (refused %lld), linked %s, commands %lld, holds %lld, "
                  "position mm (%.3f, %.3f, %.3f)",
                  static_cast<long long>(b->connections()), static_cast<long long>(b->refused()),
                  b->linked() ? "yes" : "no", static_cast<long long>(c->commands()),
                  static_cast<long long>(c->holds()), q[0], q[1], q[2]);
    return std::string(line);
  };
  LFTRACK_RETURN_IF_ERROR(serve_until_stopped(
      o, kinds,
      [&](const Fault& f) {
        if (f.kind == "unplug") {
          b->unplug();
          return true;
        }
        bool any = false;
        for (int i = 0; i < f.count; ++i) any = b->inject(static_cast<R>(kinds.at(f.kind))) || any;
        return any;
      },
      describe, announce));
  if (o.json) {
    nlohmann::json j = {{"device", "robot"}, {"connections", b->connections()}, {"commands", c->commands()},
                        {"holds", c->holds()}};
    std::printf("%s\n", j.dump().c_str());
  } else {
    std::printf("served: %s\n", describe().c_str());
  }
  return {};
}

}  // namespace

namespace serve {
std::string kind_list(const std::map<std::string, int>& kinds) {
  std::string s;
  for (const auto& [kind, value] : kinds) s += (s.empty() ? "" : ", ") + kind;
  return s;
}

void add_common(CLI::App* app, ServeOptions* o, const ServeOptionTexts& texts) {
  app->add_option("--scene", o->scene.scene, texts.scene);
  app->add_option("--room", o->room, texts.room);
  app->add_option("--fault", o->faults,
                  "KIND[:COUNT][@SECONDS]: inject a fault SECONDS after start (repeatable); KIND: " + texts.fault_kinds);
  app->add_option("--control", o->control, "Control socket (datagrams: 'fault KIND[:COUNT]', 'status', 'stop'), mode 0600");
  app->add_option("--duration", o->duration_s, "Stop after this many seconds (0: until SIGINT/SIGTERM)")
      ->check(finite_in(0, 86400));
  app->add_flag("--json", o->json, "Print the closing summary as JSON");
}
}  // namespace serve

Command add_serve_couch_command(CLI::App* parent) {
  auto o = std::make_shared<ServeOptions>();
  CLI::App* app = parent->add_subcommand("couch", "The virtual couch behind a Modbus TCP server, as its own process");
  app->add_option("--modbus", o->endpoint,
                  "tcp:ADDRESS:PORT to listen on (port 0: any free port), rtu:DEVICE (a serial port; 115200 8E1), or "
                  "rtu:pty (a pseudo-terminal pair: the first line names the client's end)")
      ->default_val("tcp:127.0.0.1:1502");
  add_common(
      app, o.get(),
      {"Scene whose actuator section gives the couch's dynamics: latency_s, max_speed_mm_s/deg_s, "
       "range_mm/deg (default: 0.15 s, 20 mm/s, 10 deg/s, 50 mm, 10 deg)",
       "Publish the couch's position in this room link file, for simulated detectors in other processes "
       "(serve detectors --room)",
       kind_list(couch_fault_kinds())});
  CLI::Option* scene = app->get_option("--scene");
  return [o, scene] {
    o->scene_given = scene->count() > 0;
    return serve_couch(*o);
  };
}

Command add_serve_robot_command(CLI::App* parent) {
  auto o = std::make_shared<ServeOptions>();
  CLI::App* app = parent->add_subcommand("robot", "The virtual robot behind a CAN bridge socket, as its own process");
  app->add_option("--socket", o->endpoint, "The bridge's socket path (SOCK_SEQPACKET of struct can_frame)")->required();
  add_common(
      app, o.get(),
      {"Scene whose actuator section gives the robot's dynamics: latency_s, max_speed_mm_s/deg_s, "
       "range_mm/deg (default: 0.15 s, 20 mm/s, 10 deg/s, 50 mm, 10 deg)",
       "Publish the robot's position in this room link file, for simulated detectors in other processes "
       "(serve detectors --room)",
       kind_list(robot_fault_kinds())});
  CLI::Option* scene = app->get_option("--scene");
  return [o, scene] {
    o->scene_given = scene->count() > 0;
    return serve_robot(*o);
  };
}

}  // namespace lftrack::cli
