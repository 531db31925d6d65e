#include "lftrack/host/actuator_lock.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>

#include <cerrno>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <map>
#include <mutex>

#include "lftrack/host/scene_devices.hpp"

namespace lftrack::host {
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

}  // namespace

std::string ActuatorLock::lock_dir() {
  if (const char* dir = std::getenv("LFTRACK_LOCK_DIR"); dir != nullptr && *dir != '\0') return dir;
  if (::access("/run/lock", W_OK | X_OK) == 0) return "/run/lock";
  return "/tmp";
}

std::string ActuatorLock::lock_path(const Scene& scene) {
  // Readable (an administrator finds the file by the couch's address) and unique (a hash of the
  // whole description: two that read alike once cleaned get two files).
  const std::string couch = describe_actuator(scene.actuator);
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
  const std::string couch = describe_actuator(scene.actuator);
  const std::string path = lock_path(scene);
  std::lock_guard<std::mutex> guard(held_mutex());
  // A forked child has the parent's entry and open file, but is another process: it locks anew.
  if (auto shared = held()[path].lock(); shared && shared->owner_ == ::getpid()) return shared;
  const int fd = open_lock_file(path);
  if (fd < 0)
    return io_error(
        fmt::format("{}: cannot open the lock of the {} ({}): set LFTRACK_LOCK_DIR to a folder "
                    "every lftrack user of this room may write",
                    path, couch, std::strerror(errno)));
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int error = errno;
    char text[kMaxHolderChars + 64] = {};
    const ssize_t n = ::pread(fd, text, sizeof text - 1, 0);
    ::close(fd);
    if (error != EWOULDBLOCK) return io_error(fmt::format("{}: cannot lock: {}", path, std::strerror(error)));
    const std::string holder = n > 0 ? printable(std::string(text, std::size_t(n)), kMaxHolderChars) : "";
    return failed_precondition(fmt::format(
        "the {} is driven by another lftrack now ({}; lock {}): one program at a time drives a couch; "
        "wait for it to end, or stop it",
        couch, holder.empty() ? std::string("which process is not recorded") : holder, path));
  }
  // Held whether or not the holder is recorded (a refused program then says it is not).
  const std::string holder = this_holder() + "\n";
  const bool recorded = ::ftruncate(fd, 0) == 0 &&
                        ::pwrite(fd, holder.data(), holder.size(), 0) == static_cast<ssize_t>(holder.size());
  (void)recorded;
  std::shared_ptr<const ActuatorLock> lock(new ActuatorLock(fd, path));
  held()[path] = lock;
  return lock;
}

ActuatorLock::~ActuatorLock() {
  // Under the mutex: an acquire of this process waits until the file is closed (else its own
  // flock would find this one's and refuse this process).
  std::lock_guard<std::mutex> guard(held_mutex());
  auto it = held().find(path_);
  if (it != held().end() && it->second.expired()) held().erase(it);
  (void)::ftruncate(fd_, 0);  // no holder named once released (still held until the close)
  ::close(fd_);
}

}  // namespace lftrack::host
