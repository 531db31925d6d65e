#include "lftrack/sim/room_link.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <string>

namespace lftrack::sim {

namespace {

// Version 2 keeps the last kHistory samples, so that a detector that exposes at a given time sees
// the couch where it was then, however late its thread gets to look (version 1 held the newest
// only: a simulated detector's rendering thread, woken late on a loaded host, saw a couch that
// had already moved on while the loop's read-back had seen it before the move, and the patient's
// offset came out wrong by the move).
constexpr char kMagic[16] = "lftrack-room2";
constexpr std::uint64_t kHistory = 1024;  // about a second at the couch server's 1 kHz

// One sample under its own sequence lock: 2n + 1 while sample n is being written into it, 2n + 2
// once it holds sample n. A reader that finds anything else there for the sample it wants lost
// it (a write under way, or the writer lapped it).
struct alignas(64) LinkSlot {
  std::atomic<std::uint64_t> sequence;
  std::int64_t written_ns;
  double position[6];
};

struct alignas(64) LinkFile {
  char magic[16];
  std::atomic<std::uint64_t> published;  // samples written in all; sample n is in slot n % kHistory
  std::uint64_t writer_pid;
  LinkSlot slots[kHistory];
};
static_assert(std::atomic<std::uint64_t>::is_always_lock_free);

// Sample n, if its slot still holds it whole and its position is finite.
bool read_slot(const LinkFile& file, std::uint64_t n, RoomLinkSample* out) {
  const LinkSlot& slot = file.slots[n % kHistory];
  const std::uint64_t want = 2 * n + 2;
  if (slot.sequence.load(std::memory_order_acquire) != want) return false;
  RoomLinkSample s;
  for (int i = 0; i < 6; ++i) s.couch_position[i] = slot.position[i];
  s.written_ns = slot.written_ns;
  std::atomic_thread_fence(std::memory_order_acquire);
  if (slot.sequence.load(std::memory_order_relaxed) != want) return false;
  s.writer_pid = file.writer_pid;
  *out = s;
  return true;
}

bool finite(const RoomLinkSample& s) { return s.couch_position.allFinite(); }

// The pid of the process that wrote an existing link (0 if none can be read).
std::uint64_t link_writer(const std::filesystem::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
  if (fd < 0) return 0;
  unsigned char bytes[offsetof(LinkFile, writer_pid) + sizeof(std::uint64_t)];
  const bool ok = ::read(fd, bytes, sizeof bytes) == ssize_t(sizeof bytes);
  ::close(fd);
  std::uint64_t pid = 0;
  if (ok) std::memcpy(&pid, bytes + offsetof(LinkFile, writer_pid), sizeof pid);
  return pid;
}

// The first 16 bytes of a regular file at `path` (never through a link, never blocking on a FIFO)
// and its size; false if there is none to read.
bool read_magic(const std::filesystem::path& path, char (&magic)[16], off_t* size) {
  struct stat link_stat {};
  if (::lstat(path.c_str(), &link_stat) != 0 || !S_ISREG(link_stat.st_mode)) return false;  // a FIFO never blocks us
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
  if (fd < 0) return false;
  struct stat st {};
  const bool ok = ::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && ::read(fd, magic, 16) == 16;
  ::close(fd);
  *size = st.st_size;
  return ok;
}

bool is_room_link(const std::filesystem::path& path) {
  char magic[16] = {};
  off_t size = 0;
  return read_magic(path, magic, &size) && size == off_t(sizeof(LinkFile)) && std::memcmp(magic, kMagic, 16) == 0;
}

// A room link of the first format (one sample, before the history), which this build cannot read.
bool is_older_room_link(const std::filesystem::path& path) {
  char magic[16] = {};
  off_t size = 0;
  return read_magic(path, magic, &size) && std::memcmp(magic, "lftrack-room1", 14) == 0;
}

std::string older_link_advice(const std::filesystem::path& path) {
  return is_older_room_link(path) ? " (a room link from an older lftrack, which kept no history: remove it once "
                                    "its server has stopped)"
                                  : "";
}

}  // namespace

Result<std::unique_ptr<RoomLinkWriter>> RoomLinkWriter::create(const std::filesystem::path& path) {
  std::error_code ec;
  const bool existing = std::filesystem::exists(std::filesystem::symlink_status(path, ec));
  if (existing) {
    if (!is_room_link(path))
      return failed_precondition("room link " + path.string() + ": a file that is not a room link is there; "
                                 "refusing to replace it" + older_link_advice(path));
  }
  const int fd = existing ? ::open(path.c_str(), O_RDWR | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK)
                          : ::open(path.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC | O_NOFOLLOW, 0600);
  if (fd < 0) return io_error("room link " + path.string() + ": " + std::strerror(errno));
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int e = errno;
    ::close(fd);
    if (e == EWOULDBLOCK)
      return failed_precondition("room link " + path.string() + ": process " + std::to_string(link_writer(path)) +
                                 " is still writing it (another `lftrack serve`?)");
    return io_error("room link " + path.string() + ": flock: " + std::strerror(e));
  }
  if (!existing && ::ftruncate(fd, sizeof(LinkFile)) != 0) {
    const int e = errno;
    ::close(fd);
    std::filesystem::remove(path, ec);
    return io_error("room link " + path.string() + ": " + std::strerror(e));
  }
  void* map = ::mmap(nullptr, sizeof(LinkFile), PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  if (map == MAP_FAILED) {
    const int e = errno;
    if (!existing) std::filesystem::remove(path, ec);
    ::close(fd);
    return io_error("room link " + path.string() + ": mmap: " + std::strerror(e));
  }
  std::unique_ptr<RoomLinkWriter> writer(new RoomLinkWriter(path, map, fd));
  auto* file = static_cast<LinkFile*>(map);
  if (existing) {  // taken over: the couch stands where the last writer left it
    RoomLinkReader reader(map);
    RoomLinkSample last;
    if (reader.read(&last)) writer->resumed_ = last.couch_position;
    reader.map_ = nullptr;  // not the reader's to unmap
    // A writer killed mid-write left that slot odd and `published` short of it: the next sample
    // goes into the same slot and completes it.
    file->writer_pid = static_cast<std::uint64_t>(::getpid());
    return writer;
  }
  file->writer_pid = static_cast<std::uint64_t>(::getpid());
  file->published.store(0, std::memory_order_relaxed);
  for (LinkSlot& slot : file->slots) slot.sequence.store(0, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  std::memcpy(file->magic, kMagic, sizeof kMagic);  // last: a reader sees a link only when it is one
  return writer;
}

RoomLinkWriter::~RoomLinkWriter() {
  ::munmap(map_, sizeof(LinkFile));
  // Only the file this writer holds: if its link was removed and another server made a new one
  // at the same path, that one is the other server's.
  struct stat ours {}, there {};
  if (!leave_file_ && ::fstat(lock_fd_, &ours) == 0 && ::lstat(path_.c_str(), &there) == 0 && ours.st_dev == there.st_dev &&
      ours.st_ino == there.st_ino) {
    std::error_code ec;
    std::filesystem::remove(path_, ec);
  }
  ::close(lock_fd_);  // after the removal: no second writer takes over a file about to go
}

void RoomLinkWriter::publish(const tracking::Vector6d& couch_position) {
  publish(couch_position, room_link_now_ns());
}

void RoomLinkWriter::publish(const tracking::Vector6d& couch_position, std::int64_t at_ns) {
  auto* file = static_cast<LinkFile*>(map_);
  const std::uint64_t n = file->published.load(std::memory_order_relaxed);
  LinkSlot& slot = file->slots[n % kHistory];
  slot.sequence.store(2 * n + 1, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  for (int i = 0; i < 6; ++i) slot.position[i] = couch_position[i];
  slot.written_ns = at_ns;
  std::atomic_thread_fence(std::memory_order_release);
  slot.sequence.store(2 * n + 2, std::memory_order_release);
  file->published.store(n + 1, std::memory_order_release);
}

Result<std::unique_ptr<RoomLinkReader>> RoomLinkReader::open(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::exists(std::filesystem::symlink_status(path, ec)))
    return not_found(
        "room link " + path.string() +
        ": missing (start the served couch or robot with `lftrack serve couch|robot ... --room " +
        path.string() + "`)");
  if (!is_room_link(path))
    return failed_precondition("room link " + path.string() + ": a file that is not a room link is there" +
                               older_link_advice(path) +
                               " (no server will replace it: remove it, or name another sim.couch_link)");
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
  if (fd < 0) return io_error("room link " + path.string() + ": " + std::strerror(errno));
  void* map = ::mmap(nullptr, sizeof(LinkFile), PROT_READ, MAP_SHARED, fd, 0);
  ::close(fd);
  if (map == MAP_FAILED) return io_error("room link " + path.string() + ": mmap: " + std::strerror(errno));
  return std::unique_ptr<RoomLinkReader>(new RoomLinkReader(map));
}

std::int64_t room_link_now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

bool RoomLinkReader::writer_running(const std::filesystem::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
  if (fd < 0) return false;
  const bool held = ::flock(fd, LOCK_SH | LOCK_NB) != 0 && errno == EWOULDBLOCK;
  ::close(fd);  // releases the probe's shared lock, if it took one
  return held;
}

RoomLinkReader::~RoomLinkReader() {
  if (map_ != nullptr) ::munmap(const_cast<void*>(map_), sizeof(LinkFile));
}

bool RoomLinkReader::read(RoomLinkSample* sample) const {
  const auto* file = static_cast<const LinkFile*>(map_);
  for (int attempt = 0; attempt < 64; ++attempt) {
    const std::uint64_t n = file->published.load(std::memory_order_acquire);
    if (n == 0) return false;  // nothing written yet
    RoomLinkSample s;
    if (!read_slot(*file, n - 1, &s)) continue;  // lapped by the writer: the newest is newer
    if (!finite(s)) return false;
    *sample = s;
    return true;
  }
  return false;
}

bool RoomLinkReader::read_at(std::int64_t t_ns, RoomLinkSample* sample) const {
  const auto* file = static_cast<const LinkFile*>(map_);
  for (int attempt = 0; attempt < 64; ++attempt) {
    const std::uint64_t n = file->published.load(std::memory_order_acquire);
    if (n == 0) return false;
    // From the newest back to the first sample written at or before t_ns.
    RoomLinkSample later, s;
    bool have_later = false, lapped = false;
    const std::uint64_t oldest = n > kHistory ? n - kHistory : 0;
    for (std::uint64_t j = n; j-- > oldest;) {
      if (!read_slot(*file, j, &s)) {
        lapped = true;
        break;
      }
      if (!finite(s)) return false;
      if (s.written_ns <= t_ns) break;
      later = s;
      have_later = true;
      if (j == oldest) {  // t_ns is older than everything kept: the oldest is the nearest
        *sample = later;
        return true;
      }
    }
    if (lapped) {
      if (!have_later) continue;  // the newest went while we looked: start again
      *sample = later;            // the history before `later` is gone: the nearest kept
      return true;
    }
    if (!have_later || later.written_ns <= s.written_ns) {  // at or after the newest sample
      *sample = s;
      return true;
    }
    // Between two samples: the couch moves at a bounded speed, so a straight line between them.
    const double f = double(t_ns - s.written_ns) / double(later.written_ns - s.written_ns);  // in [0, 1)
    const tracking::Vector6d between = s.couch_position + f * (later.couch_position - s.couch_position);
    if (!between.allFinite()) return false;  // finite ends, but far enough apart to overflow
    sample->couch_position = between;
    sample->written_ns = t_ns;
    sample->writer_pid = s.writer_pid;
    return true;
  }
  return false;
}

}  // namespace lftrack::sim
