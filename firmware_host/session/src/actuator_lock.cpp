#include "lftrack/session/actuator_lock.hpp"

#include <fcntl.h>
#include <netdb.h>
#include <sys/file.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>

#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <mutex>
#include <thread>

#include "lftrack/session/scene_devices.hpp"

namespace lftrack::session {
namespace {

constexpr std::size_t kMaxHolderChars = 300;

// Printable ASCII of `text`, at most `limit` characters (what a holder wrote, or this process's
// command line, is shown in a message).
std::string printable(const std::string& text, std::size_t limit) {
  std::string out;
  for (char c : text) {
    if (out.size() >= limit) break;
    out += (c >= 0x20 && c < 0x7f) ? c : ' ';
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

// "pid 1234: lftrack run --scene room.yaml" for this process.
std::string this_holder() {
  std::ifstream in("/proc/self/cmdline", std::ios::binary);
  std::string command((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return fmt::format("pid {}: {}", ::getpid(), printable(command, kMaxHolderChars));
}

// The lock file opened (made where missing). An existing file is opened without O_CREAT: in a
// sticky folder (/run/lock, /tmp) the kernel's protected_regular refuses O_CREAT on another user's
// file, even where its mode lets this user write it.
int open_lock_file(const std::string& path) {
  for (int attempt = 0; attempt < 3; ++attempt) {
    int fd = ::open(path.c_str(), O_RDWR | O_CLOEXEC | O_NOFOLLOW);
    if (fd >= 0 || errno != ENOENT) return fd;
    fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC | O_NOFOLLOW, 0666);
    if (fd >= 0) {
      (void)::fchmod(fd, 0666);  // any user's lftrack of this couch may take it (the umask aside)
      return fd;
    }
    if (errno != EEXIST) return fd;  // EEXIST: another process made it first; open theirs
  }
  return -1;
}

// Within one process the lock is shared (flock locks belong to an open file: a second open in
// this process would refuse this process). Entries are this process's only (owner_, after fork).
std::mutex& held_mutex() {
  static std::mutex m;
  return m;
}
std::map<std::string, std::weak_ptr<const ActuatorLock>>& held() {
  static std::map<std::string, std::weak_ptr<const ActuatorLock>> h;
  return h;
}

// `host` as a numeric address (an IPv4 one where it has one: "localhost", "127.1" and
// "127.0.0.1" are one couch); lower-case where it does not resolve.
std::string numeric_host(const std::string& host) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  std::string best;
  if (::getaddrinfo(host.c_str(), nullptr, &hints, &found) == 0) {
    for (const addrinfo* a = found; a != nullptr; a = a->ai_next) {
      char text[NI_MAXHOST] = {};
      if (::getnameinfo(a->ai_addr, a->ai_addrlen, text, sizeof text, nullptr, 0, NI_NUMERICHOST) != 0)
        continue;
      if (best.empty() || a->ai_family == AF_INET) best = text;
      if (a->ai_family == AF_INET) break;
    }
    ::freeaddrinfo(found);
  }
  if (!best.empty()) return best;
  std::string lower = host;
  for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return lower;
}

// A path as the kernel would reach it (links followed where they exist).
std::string canonical_path(const std::string& path) {
  std::error_code ec;
  const std::filesystem::path p = std::filesystem::weakly_canonical(path, ec);
  return ec ? path : p.string();
}

}  // namespace

std::string ActuatorLock::couch_identity(const Scene& scene) {
  const ActuatorSpec& a = scene.actuator;
  if (a.type == "modbus") {
    const drivers::ModbusCouchOptions& m = a.modbus;
    if (m.transport == drivers::ModbusCouchOptions::Transport::kTcp)
      return fmt::format("modbus tcp {}:{}", numeric_host(m.host), m.port);
    return "modbus rtu " + canonical_path(m.serial_device);
  }
  if (a.type == "can")
    return a.can.bridge_path.empty() ? "can " + a.can.interface : "can bridge " + canonical_path(a.can.bridge_path);
  return a.type;
}

std::string ActuatorLock::lock_dir() {
  if (const char* dir = std::getenv(kTestLockDirVariable); dir != nullptr && *dir != '\0') return dir;
  std::error_code ec;
  if (std::filesystem::is_directory("/run/lock", ec)) return "/run/lock";
  return "/tmp";
}

std::string ActuatorLock::lock_path(const Scene& scene) {
  // Readable (an administrator finds the file by the couch's address) and unique (a hash of the
  // whole identity: two that read alike once cleaned get two files).
  const std::string couch = couch_identity(scene);
  std::string name;
  for (char c : couch) {
    if (name.size() >= 80) break;
    const bool plain = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.';
    name += plain ? c : '-';
  }
  std::uint64_t hash = 1469598103934665603ull;  // FNV-1a 64
  for (unsigned char c : couch) hash = (hash ^ c) * 1099511628211ull;
  return fmt::format("{}/lftrack-actuator-{}-{:08x}.lock", lock_dir(), name, hash & 0xFFFFFFFFu);
}

Result<std::shared_ptr<const ActuatorLock>> ActuatorLock::acquire(const Scene& scene) {
  if (!actuator_is_device(scene))
    return invalid_argument("an actuator lock is for a device (modbus, can), not " + scene.actuator.type);
  const char* env_dir = std::getenv(kTestLockDirVariable);
  if (env_dir != nullptr && *env_dir != '\0' && env_dir[0] != '/')
    return invalid_argument(fmt::format(
        "{} {} is not an absolute path: programs started in other folders would lock another file for the "
        "same couch",
        kTestLockDirVariable, env_dir));
  const std::string couch = describe_actuator(scene.actuator);
  const std::string path = lock_path(scene);
  const std::string me = fmt::format("pid {}:", ::getpid());
  // This process's own lock, released by another of its threads while this one asks, is still
  // open until its destructor has closed it: asked again for a while, not refused.
  for (int attempt = 0;; ++attempt) {
    std::unique_lock<std::mutex> guard(held_mutex());
    // A forked child has the parent's entry and open file, but is another process: it locks anew.
    if (auto shared = held()[path].lock(); shared && shared->owner_ == ::getpid()) return shared;
    const int fd = open_lock_file(path);
    if (fd < 0)
      return io_error(fmt::format(
          "{}: cannot open the lock of the {} ({}); the couch is not driven without it: every lftrack "
          "program on this host takes its couch's lock in /run/lock (the service units make it writable)",
          path, couch, std::strerror(errno)));
    if (::flock(fd, LOCK_EX | LOCK_NB) == 0) {
      // Held whether or not the holder is recorded (a refused program then says it is not).
      const std::string holder = this_holder() + "\n";
      const bool recorded = ::ftruncate(fd, 0) == 0 && ::pwrite(fd, holder.data(), holder.size(), 0) ==
                                                           static_cast<ssize_t>(holder.size());
      (void)recorded;
      std::shared_ptr<const ActuatorLock> lock(new ActuatorLock(fd, path));
      held()[path] = lock;
      return lock;
    }
    const int error = errno;
    char text[kMaxHolderChars + 64] = {};
    const ssize_t n = ::pread(fd, text, sizeof text - 1, 0);
    ::close(fd);
    if (error != EWOULDBLOCK) return io_error(fmt::format("{}: cannot lock: {}", path, std::strerror(error)));
    const std::string holder = n > 0 ? printable(std::string(text, std::size_t(n)), kMaxHolderChars) : "";
    if (holder.rfind(me, 0) == 0 && attempt < 100) {
      guard.unlock();
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      continue;
    }
    return failed_precondition(fmt::format(
        "the {} is driven by another lftrack now ({}; lock {}): one program at a time drives a couch; "
        "wait for it to end, or stop it",
        couch, holder.empty() ? std::string("which process is not recorded") : holder, path));
  }
}

ActuatorLock::~ActuatorLock() {
  std::lock_guard<std::mutex> guard(held_mutex());
  auto it = held().find(path_);
  if (it != held().end() && it->second.expired()) held().erase(it);
  // No holder named once released (still held until the close); a forked child's copy leaves the
  // parent's line alone.
  if (owner_ == ::getpid()) (void)::ftruncate(fd_, 0);
  ::close(fd_);
}

}  // namespace lftrack::session
