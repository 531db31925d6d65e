// `lftrack serve tracker`: the optical tracker's twin as a process of its own (sim/tracker_twin.hpp):
// an OpenIGTLink server streaming a chest marker that breathes as the scene's surrogate.sim says
// (its period motion.breathing's, its noise from sim.seed), from the moment the server starts, as
// PLUS would stream a real marker. What surrogate.source igtl reads (drivers/igtl_surrogate.hpp).

#include <spdlog/spdlog.h>

#include <atomic>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>

#include "lftrack/drivers/igtl_surrogate.hpp"
#include "lftrack/sim/breathing_surrogate.hpp"
#include "lftrack/sim/tracker_twin.hpp"
#include "lftrack/watch/listen_address.hpp"
#include "serve_common.hpp"

namespace lftrack::cli {

using session::load_scene;

using watch::parse_listen_address;
using watch::reachable_warning;

using namespace serve;

namespace {

struct TrackerOptions {
  ServeOptions serve;
  std::string listen = "127.0.0.1:18944";
  std::string device;  // "": the scene's surrogate.igtl.device, else Marker
  std::string message = "transform";
  double rate_hz = 0;  // 0: the scene's surrogate.rate_hz
};

// The faults a tracker shows: its stream stops, its marker freezes, or jumps (on the skin).
const std::map<std::string, int>& tracker_fault_kinds() {
  static const std::map<std::string, int> kinds = {{"stop", 0}, {"freeze", 1}, {"jump", 2}};
  return kinds;
}

// What the faults change, between the serving thread (which injects) and the twin's (which sends).
struct MarkerFaults {
  std::atomic<std::int64_t> stop_until_ns{0}, freeze_until_ns{0};
  std::atomic<double> jump_mm{0};
};

std::int64_t monotonic_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

Status serve_tracker(const TrackerOptions& o) {
  auto scene = load_scene(o.serve.scene.scene);
  if (!scene.ok()) return scene.status();
  auto at = parse_listen_address(o.listen);
  if (!at.ok()) return at.status().with_context("--listen");
  if (!o.device.empty())
    if (const std::string why = drivers::igtl_device_name_problem(o.device); !why.empty())
      return invalid_argument("--device \"" + o.device + "\": " + why);
  sim::TrackerTwinOptions twin;
  twin.address = at->address;
  twin.port = at->port;
  twin.device = !o.device.empty()                       ? o.device
                : !scene->surrogate.igtl_device.empty() ? scene->surrogate.igtl_device
                                                        : "Marker";
  twin.position_messages = o.message == "position";
  twin.rate_hz = o.rate_hz > 0 ? o.rate_hz : std::min(1000.0, scene->loop.imaging.surrogate.rate_hz);
  sim_spec::BreathingSurrogateSpec chest = scene->surrogate.sim;
  chest.sample_rate_hz = twin.rate_hz;
  auto marker = std::make_shared<sim::BreathingSurrogate>(chest);
  auto faults = std::make_shared<MarkerFaults>();
  auto frozen = std::make_shared<double>(0);
  const Eigen::Vector3d axis = scene->surrogate.igtl_axis;
  const std::int64_t start_ns = monotonic_ns();
  // Called on the twin's thread only (marker's noise and `frozen` are its own).
  auto served = sim::TrackerTwin::start(twin, [=](std::int64_t t_ns, Eigen::Vector3d* p) {
    if (t_ns < faults->stop_until_ns.load()) return false;
    double s = marker->sample(1e-9 * double(t_ns - start_ns)) + faults->jump_mm.load();
    if (t_ns < faults->freeze_until_ns.load())
      s = *frozen;
    else
      *frozen = s;
    *p = axis * s;
    return true;
  });
  if (!served.ok()) return served.status();
  sim::TrackerTwin* server = served->get();
  at->port = server->port();
  const std::string w = reachable_warning(*at, "the tracker's twin", "read the simulated marker");
  if (!w.empty()) spdlog::warn("{}", w);
  const auto describe = [&] {
    char line[160];
    std::snprintf(line, sizeof line, "messages %lld, clients %lld now (%lld in all)",
                  static_cast<long long>(server->messages_sent()),
                  static_cast<long long>(server->clients_now()),
                  static_cast<long long>(server->clients_total()));
    return std::string(line);
  };
  LFTRACK_RETURN_IF_ERROR(serve_until_stopped(
      o.serve, tracker_fault_kinds(),
      [&](const Fault& f) {
        const std::int64_t now = monotonic_ns();
        if (f.kind == "stop") faults->stop_until_ns.store(now + std::int64_t{f.count} * 1'000'000'000);
        if (f.kind == "freeze") faults->freeze_until_ns.store(now + std::int64_t{f.count} * 1'000'000'000);
        if (f.kind == "jump") faults->jump_mm.store(faults->jump_mm.load() + f.count);
        return true;
      },
      describe,
      [&] {
        std::printf("lftrack serve tracker: openigtlink %s (%s \"%s\" at %g Hz)\n", at->text().c_str(),
                    twin.position_messages ? "POSITION" : "TRANSFORM", twin.device.c_str(), twin.rate_hz);
      }));
  if (o.serve.json) {
    const nlohmann::json j = {{"device", "tracker"},
                              {"listen", at->text()},
                              {"marker_device", twin.device},
                              {"message", twin.position_messages ? "POSITION" : "TRANSFORM"},
                              {"messages", server->messages_sent()},
                              {"clients_total", server->clients_total()}};
    std::printf("%s\n", j.dump().c_str());
  } else {
    std::printf("served: %s\n", describe().c_str());
  }
  return {};
}

}  // namespace

Command add_serve_tracker_command(CLI::App* parent) {
  auto o = std::make_shared<TrackerOptions>();
  CLI::App* app = parent->add_subcommand(
      "tracker", "The optical tracker's twin: a breathing chest marker over OpenIGTLink, as its own process");
  app->add_option(
      "--scene", o->serve.scene.scene,
      "Scene whose surrogate section gives the marker (surrogate.sim: travel, lead, drift, noise; "
      "surrogate.igtl: axis and device; motion.breathing: period) (default: the built-in scene's)");
  app->add_option("--listen", o->listen, "[ADDRESS:]PORT to listen on (port 0: any free port)")
      ->default_val("127.0.0.1:18944");
  app->add_option("--device", o->device,
                  "The marker's OpenIGTLink device name (default: the scene's, else Marker)");
  app->add_option("--message", o->message, "TRANSFORM messages (as PLUS sends a tool) or POSITION")
      ->check(CLI::IsMember({"transform", "position"}))
      ->default_val("transform");
  app->add_option(
         "--rate", o->rate_hz,
         "Messages per second, 5 to 1000, as surrogate.rate_hz (default: the scene's surrogate.rate_hz)")
      ->check(finite_in(5, 1000));
  app->add_option(
      "--fault", o->serve.faults,
      "KIND[:COUNT][@SECONDS]: inject a fault SECONDS after start (repeatable); KIND: stop (no messages "
      "for COUNT s), freeze (the marker repeats its reading for COUNT s), jump (the marker steps by "
      "COUNT mm, for good)");
  app->add_option("--control", o->serve.control,
                  "Control socket (datagrams: 'fault KIND[:COUNT]', 'status', 'stop'), mode 0600");
  app->add_option("--duration", o->serve.duration_s, "Stop after this many seconds (0: until SIGINT/SIGTERM)")
      ->check(finite_in(0, 86400));
  app->add_flag("--json", o->serve.json, "Print the closing summary as JSON");
  return [o] { return serve_tracker(*o); };
}

}  // namespace lftrack::cli
