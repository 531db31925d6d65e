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

namespace lftrack::sim {

namespace {

constexpr char kMagic[16] = "lftrack-room1";

struct alignas(64) LinkFile {
  char magic[16];
  std::atomic<std::uint64_t> sequence;  // odd while a write is in progress
  std::uint64_t writer_pid;
  std::int64_t written_ns;
  double position[6];
};
static_assert(std::atomic<std::uint64_t>::is_always_lock_free);

std::int64_t monotonic_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// The pid of the process that wrote an existing link (0 if none can be read).
std::uint64_t link_writer(const std::filesystem::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
  if (fd < 0) return 0;
  unsigned char bytes[sizeof(LinkFile)];
  const bool ok = ::read(fd, bytes, sizeof bytes) == ssize_t(sizeof bytes);
  ::close(fd);
  std::uint64_t pid = 0;
  if (ok) std::memcpy(&pid, bytes + offsetof(LinkFile, writer_pid), sizeof pid);
  return pid;
}

bool is_room_link(const std::filesystem::path& path) {
  struct stat link_stat {};
  if (::lstat(path.c_str(), &link_stat) != 0 || !S_ISREG(link_stat.st_mode)) return false;  // a FIFO never blocks us
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
  if (fd < 0) return false;
  char magic[16] = {};
  struct stat st {};
  const bool ok = ::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size == sizeof(LinkFile) &&
                  ::read(fd, magic, sizeof magic) == ssize_t(sizeof magic) && std::memcmp(magic, kMagic, 16) == 0;
  ::close(fd);
  return ok;
}

}  // namespace

Result<std::unique_ptr<RoomLinkWriter>> RoomLinkWriter::create(const std::filesystem::path& path) {
  std::error_code ec;
  const bool existing = std::filesystem::exists(std::filesystem::symlink_status(path, ec));
  if (existing) {
    if (!is_room_link(path))
      return failed_precondition("room link " + path.string() + ": a file that is not a room link is there; "
                                 "refusing to replace it");
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
    if (file->sequence.load() % 2 != 0) file->sequence.fetch_add(1);  // a writer killed mid-write
    file->writer_pid = static_cast<std::uint64_t>(::getpid());
    return writer;
  }
  file->writer_pid = static_cast<std::uint64_t>(::getpid());
  file->sequence.store(0, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  std::memcpy(file->magic, kMagic, sizeof kMagic);  // last: a reader sees a link only when it is one
  return writer;
}

RoomLinkWriter::~RoomLinkWriter() {
  ::munmap(map_, sizeof(LinkFile));
  std::error_code ec;
  std::filesystem::remove(path_, ec);
  ::close(lock_fd_);  // after the removal: no second writer takes over a file about to go
}

void RoomLinkWriter::publish(const tracking::Vector6d& couch_position) {
  auto* file = static_cast<LinkFile*>(map_);
  const std::uint64_t s = file->sequence.load(std::memory_order_relaxed);
  file->sequence.store(s + 1, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  for (int i = 0; i < 6; ++i) file->position[i] = couch_position[i];
  file->written_ns = monotonic_ns();
  std::atomic_thread_fence(std::memory_order_release);
  file->sequence.store(s + 2, std::memory_order_release);
}

Result<std::unique_ptr<RoomLinkReader>> RoomLinkReader::open(const std::filesystem::path& path) {
  if (!is_room_link(path))
    return not_found("room link " + path.string() + ": missing or not a room link (start the couch with "
                     "`lftrack serve couch --room " + path.string() + "`)");
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
  if (fd < 0) return io_error("room link " + path.string() + ": " + std::strerror(errno));
  void* map = ::mmap(nullptr, sizeof(LinkFile), PROT_READ, MAP_SHARED, fd, 0);
  ::close(fd);
  if (map == MAP_FAILED) return io_error("room link " + path.string() + ": mmap: " + std::strerror(errno));
  return std::unique_ptr<RoomLinkReader>(new RoomLinkReader(map));
}

RoomLinkReader::~RoomLinkReader() {
  if (map_ != nullptr) ::munmap(const_cast<void*>(map_), sizeof(LinkFile));
}

bool RoomLinkReader::read(RoomLinkSample* sample) const {
  const auto* file = static_cast<const LinkFile*>(map_);
  for (int attempt = 0; attempt < 64; ++attempt) {
    const std::uint64_t before = file->sequence.load(std::memory_order_acquire);
    if (before == 0) return false;  // nothing written yet
    if ((before & 1) != 0) continue;
    RoomLinkSample s;
    for (int i = 0; i < 6; ++i) s.couch_position[i] = file->position[i];
    s.written_ns = file->written_ns;
    s.writer_pid = file->writer_pid;
    std::atomic_thread_fence(std::memory_order_acquire);
    if (file->sequence.load(std::memory_order_relaxed) != before) continue;
    bool finite = true;
    for (int i = 0; i < 6; ++i) finite = finite && std::isfinite(s.couch_position[i]);
    if (!finite) return false;
    *sample = s;
    return true;
  }
  return false;
}

}  // namespace lftrack::sim
