#pragma once
// What `lftrack serve couch|robot|detectors` share: the options every server takes, faults from
// the command line (`--fault KIND[:COUNT][@SECONDS]`) and from a control socket (datagrams
// `fault KIND[:COUNT]`, `status`, `stop`; mode 0600), and the wait until a signal, --duration or
// `stop`.

#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "cli_commands.hpp"

namespace lftrack::cli::serve {

inline std::atomic<bool> g_stop{false};
extern "C" inline void on_stop_signal(int) {
  g_stop.store(true);
}

struct ServeOptions {
  SceneOptions scene;  // couch, robot: the dynamics (the actuator section's); detectors: the room
  bool scene_given = false;
  std::string endpoint;  // couch: tcp:ADDRESS:PORT; robot: the bridge socket path
  std::vector<std::string> addresses;  // detectors: where the GigE cameras listen
  std::vector<std::string> loopback;   // detectors: v4l2loopback devices instead
  std::string lf_dir;                  // detectors: light fields of the simulated frames
  double settle_s = 2;                 // detectors: the residual is summarised after this
  std::string room;
  std::vector<std::string> faults;
  std::string control;
  double duration_s = 0;
  bool json = false;
};

struct Fault {
  std::string kind;
  int count = 1;
  double at_s = 0;
  bool done = false;
};

// --duration and the like: finite, from 0 to `max`.
inline Status check_seconds(double s, const char* what, double max) {
  if (!std::isfinite(s) || s < 0 || s > max)
    return invalid_argument(std::string(what) + " must be a finite number of seconds from 0 to " + std::to_string(int(max)));
  return {};
}

// KIND[:COUNT][@SECONDS]
inline Result<Fault> parse_fault(const std::string& text, const std::map<std::string, int>& kinds, bool timed) {
  Fault f;
  std::string rest = text;
  if (const auto at = rest.find('@'); at != std::string::npos) {
    if (!timed) return invalid_argument("'" + text + "': a fault sent now takes no @time");
    char* end = nullptr;
    f.at_s = std::strtod(rest.c_str() + at + 1, &end);
    if (end == rest.c_str() + at + 1 || *end != '\0' || !std::isfinite(f.at_s) || f.at_s < 0 || f.at_s > 86400)
      return invalid_argument("'" + text + "': @SECONDS must be a time from 0 to 86400 s");
    rest.resize(at);
  }
  if (const auto colon = rest.find(':'); colon != std::string::npos) {
    char* end = nullptr;
    const long n = std::strtol(rest.c_str() + colon + 1, &end, 10);
    if (end == rest.c_str() + colon + 1 || *end != '\0' || n < 1 || n > 1000000)
      return invalid_argument("'" + text + "': COUNT must be 1 to 1000000");
    f.count = static_cast<int>(n);
    rest.resize(colon);
  }
  if (!kinds.count(rest)) {
    std::string known;
    for (const auto& [k, v] : kinds) known += (known.empty() ? "" : ", ") + k;
    return invalid_argument("unknown fault '" + rest + "' (known: " + known + ")");
  }
  f.kind = rest;
  return f;
}

// A datagram socket for faults and status while serving; mode 0600, only an absent path or a
// stale socket is replaced.
class ServeControl {
 public:
  // Whether `path` can become the control socket: short enough, its folder there, and nothing
  // at it but a stale datagram socket of a server that has gone (a live one, a socket of another
  // kind, or any other file is refused). Checked before a server binds anything; *stale says
  // whether a stale socket is to be replaced.
  static Status check_path(const std::string& path, bool* stale = nullptr) {
    if (stale != nullptr) *stale = false;
    if (path.empty()) return {};
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    if (path.size() >= sizeof a.sun_path) return invalid_argument("--control path is too long: " + path);
    std::memcpy(a.sun_path, path.data(), path.size());
    const std::filesystem::path parent = std::filesystem::path(path).parent_path();
    std::error_code ec;
    if (!parent.empty() && !std::filesystem::is_directory(parent, ec))
      return not_found("--control " + path + ": no folder " + parent.string());
    struct stat st {};
    if (::lstat(path.c_str(), &st) != 0) return {};
    if (!S_ISSOCK(st.st_mode)) return failed_precondition("--control " + path + ": a file is there; refusing to replace it");
    const int probe = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    const bool gone = ::connect(probe, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 && errno == ECONNREFUSED;
    ::close(probe);
    if (!gone) return failed_precondition("--control " + path + ": a socket in use is there; refusing to replace it");
    if (stale != nullptr) *stale = true;
    return {};
  }

  static Result<ServeControl> open(const std::string& path) {
    ServeControl c;
    if (path.empty()) return c;
    bool stale = false;
    LFTRACK_RETURN_IF_ERROR(check_path(path, &stale));
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::memcpy(a.sun_path, path.data(), path.size());
    if (stale) ::unlink(path.c_str());
    c.fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
    if (c.fd_ < 0 || ::bind(c.fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || ::chmod(path.c_str(), 0600) != 0)
      return io_error("--control " + path + ": " + std::strerror(errno));
    c.path_ = path;
    return c;
  }
  ServeControl() = default;
  ServeControl(ServeControl&& o) noexcept : fd_(o.fd_), path_(std::move(o.path_)) { o.fd_ = -1; }
  ~ServeControl() {
    if (fd_ >= 0) {
      ::close(fd_);
      ::unlink(path_.c_str());
    }
  }
  // Each waiting datagram is answered with what `handle` returns.
  template <class Handle>
  void serve(Handle&& handle) {
    if (fd_ < 0) return;
    char buffer[256];
    for (;;) {
      sockaddr_un from{};
      socklen_t length = sizeof from;
      const ssize_t n = ::recvfrom(fd_, buffer, sizeof buffer - 1, MSG_TRUNC, reinterpret_cast<sockaddr*>(&from), &length);
      if (n < 0) return;
      std::string text(buffer, static_cast<std::size_t>(std::min<ssize_t>(n, sizeof buffer - 1)));
      while (!text.empty() && (text.back() == '\n' || text.back() == '\r')) text.pop_back();
      const std::string reply = n >= ssize_t(sizeof buffer - 1) ? std::string("refused: too long") : handle(text);
      if (length > sizeof(sa_family_t))
        ::sendto(fd_, reply.data(), reply.size(), MSG_DONTWAIT, reinterpret_cast<sockaddr*>(&from), length);
    }
  }

 private:
  int fd_ = -1;
  std::string path_;
};

// --duration, --control and every --fault, checked before a server binds anything (a typo in a
// fault refuses the server rather than leaving a port bound and a fault that never comes).
inline Result<std::vector<Fault>> check_serve_options(const ServeOptions& o, const std::map<std::string, int>& kinds) {
  LFTRACK_RETURN_IF_ERROR(check_seconds(o.duration_s, "--duration", 86400));
  LFTRACK_RETURN_IF_ERROR(ServeControl::check_path(o.control));
  if (!o.control.empty() && !o.room.empty() &&
      std::filesystem::path(o.control).lexically_normal() == std::filesystem::path(o.room).lexically_normal())
    return invalid_argument("--control and --room name the same path: " + o.control);
  std::vector<Fault> timed;
  for (const std::string& text : o.faults) {
    auto f = parse_fault(text, kinds, true);
    if (!f.ok()) return f.status().with_context("--fault");
    timed.push_back(*f);
  }
  return timed;
}

// Runs until a signal, --duration, or `stop` on the control socket: timed faults, control
// datagrams. `inject` applies a fault; `status` describes the device now; `announce` prints the
// server's first line, which scripts and tests wait for: it is called once the control socket
// is bound, so that whoever reads the line can use the socket at once (a test that read it and
// sent `stop` before the bind, on a loaded host, found no socket there).
template <class Inject, class Describe, class Announce>
Status serve_until_stopped(const ServeOptions& o, const std::map<std::string, int>& kinds, Inject&& inject,
                           Describe&& status, Announce&& announce) {
  auto checked = check_serve_options(o, kinds);
  if (!checked.ok()) return checked.status();
  std::vector<Fault> timed = std::move(*checked);
  auto control = ServeControl::open(o.control);
  if (!control.ok()) return control.status();
  struct sigaction action {};
  action.sa_handler = on_stop_signal;
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
  sigaction(SIGHUP, &action, nullptr);  // a closed terminal: stop as cleanly, the control socket removed
  announce();
  std::fflush(stdout);
  const auto start = std::chrono::steady_clock::now();
  bool stop = false;
  while (!g_stop.load() && !stop) {
    const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (o.duration_s > 0 && t >= o.duration_s) break;
    for (Fault& f : timed)
      if (!f.done && t >= f.at_s) {
        f.done = true;
        spdlog::info("fault {} x{} at {:.2f} s: {}", f.kind, f.count, t, inject(f) ? "injected" : "not injected (no client)");
      }
    control->serve([&](const std::string& text) -> std::string {
      if (text == "status") return status();
      if (text == "stop") {
        stop = true;
        return "stopping";
      }
      if (text.rfind("fault ", 0) == 0) {
        auto f = parse_fault(text.substr(6), kinds, false);
        if (!f.ok()) return "refused: " + f.status().message();
        spdlog::info("fault {} x{} (control socket)", f->kind, f->count);
        return inject(*f) ? "injected: " + f->kind : "refused: no client linked";
      }
      return "refused: commands are 'fault KIND[:COUNT]', 'status', 'stop'";
    });
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return {};
}

// What the options every server takes do for one server: its own texts for --scene and --room,
// and its fault kinds for --fault (a help that describes another server's options misleads).
struct ServeOptionTexts {
  std::string scene;  // --scene: what this server takes from the scene
  std::string room;   // --room: what this server does with the room link file
  std::string fault_kinds;  // the KINDs --fault takes, in words
};
// --scene, --room, --fault, --control, --duration, --json (cmd_serve.cpp).
void add_common(CLI::App* app, ServeOptions* o, const ServeOptionTexts& texts);
// The kinds of `kinds`, comma-separated.
std::string kind_list(const std::map<std::string, int>& kinds);

}  // namespace lftrack::cli::serve
