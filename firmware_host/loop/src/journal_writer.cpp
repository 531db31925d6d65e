// The journal's writer (journal.hpp): records queued by the cycle, written and synced by a thread
// of their own.

#include "lftrack/loop/journal.hpp"

#include "lftrack/loop/realtime_setup.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstddef>
#include <cstring>
#include <optional>

#include "lftrack/loop/crc32c.hpp"
#include "lftrack/loop/journal_format.hpp"

namespace lftrack::loop {

using namespace journal_format;  // NOLINT(google-build-using-namespace): the format's constants

namespace {

void encode(const JournalRecord& r, unsigned char* out) {
  const std::uint32_t magic = kFrameMagic, size = sizeof(JournalRecord);
  std::memcpy(out, &magic, 4);
  std::memcpy(out + 4, &size, 4);
  std::memcpy(out + 8, &r, sizeof r);
  const std::uint32_t crc = crc32c(out + 8, sizeof r);
  std::memcpy(out + 8 + sizeof r, &crc, 4);
}

// Writes all of `p` to the sink (null: the file), retrying short writes and EINTR.
bool write_all(JournalSink* sink, int fd, const unsigned char* p, std::size_t n) {
  while (n > 0) {
    const ssize_t w = sink != nullptr ? sink->write(fd, p, n) : ::write(fd, p, n);
    if (w == 0) return false;
    if (w < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    p += w;
    n -= static_cast<std::size_t>(w);
  }
  return true;
}

}  // namespace

JournalWriter::JournalWriter(int fd, const JournalOptions& options)
    : fd_(fd), options_(options), queue_(options.queue_capacity) {}

JournalWriter::~JournalWriter() {
  (void)close();
}

Status check_journal_path(const std::filesystem::path& file, bool overwrite) {
  struct stat st {};
  if (::lstat(file.c_str(), &st) != 0) return {};  // nothing there (or the open will say why)
  const std::string refused = file.string() + ": a journal or another file is already there; lftrack never "
                                              "overwrites a record: choose another --journal";
  if (!overwrite) return failed_precondition(refused + ", or pass --overwrite to replace an earlier journal");
  if (!S_ISREG(st.st_mode))
    return failed_precondition(refused + " (--overwrite replaces only a regular file, never through a link)");
  if (st.st_size == 0) return {};
  unsigned char magic[8] = {};
  const int fd = ::open(file.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  const bool is_journal = fd >= 0 && ::read(fd, magic, 8) == 8 && std::memcmp(magic, kFileMagic, 8) == 0;
  // A writer holds its journal's lock for as long as it runs (open(), below).
  const bool in_use = fd >= 0 && ::flock(fd, LOCK_SH | LOCK_NB) != 0 && errno == EWOULDBLOCK;
  if (fd >= 0) ::close(fd);
  if (!is_journal)
    return failed_precondition(refused + " (it is not an lftrack journal: --overwrite replaces only a journal)");
  if (in_use)
    return failed_precondition(file.string() + ": a running lftrack is writing this journal; --overwrite replaces "
                                               "only a finished one");
  return {};
}

Result<std::unique_ptr<JournalWriter>> JournalWriter::open(const std::filesystem::path& requested,
                                                           const JournalOptions& options) {
  std::filesystem::path file = requested;
  int fd = -1;
  if (options.overwrite) {
    LFTRACK_RETURN_IF_ERROR(check_journal_path(file, true));
    // Locked before it is emptied: a journal a running lftrack writes (it holds the lock) is
    // never truncated under it (issue 50 probe: --overwrite destroyed a live run's records).
    fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_NOFOLLOW | O_CLOEXEC, 0644);
    if (fd >= 0 && ::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      ::close(fd);
      return failed_precondition(file.string() + ": a running lftrack is writing this journal; --overwrite "
                                                 "replaces only a finished one");
    }
    if (fd >= 0 && ::ftruncate(fd, 0) != 0) {
      const std::string why = std::strerror(errno);
      ::close(fd);
      return io_error(file.string() + ": cannot empty the earlier journal: " + why);
    }
  } else {
    // Created and claimed in one step (O_EXCL), so two runs can never share a file; with
    // add_suffix, the next free name of -2, -3, ... is taken instead of refusing.
    const std::string stem = (file.parent_path() / file.stem()).string(), ext = file.extension().string();
    for (int k = 2;; ++k) {
      fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
      if (fd >= 0 || errno != EEXIST || !options.add_suffix || k > 999) break;
      file = stem + "-" + std::to_string(k) + ext;
    }
    if (fd < 0 && errno == EEXIST) return check_journal_path(file, false);
    if (fd >= 0) (void)::flock(fd, LOCK_EX | LOCK_NB);  // new and ours alone: held while we write
  }
  if (fd < 0) return io_error(file.string() + ": cannot create journal: " + std::strerror(errno));
  unsigned char header[kHeaderBytes] = {};
  std::memcpy(header, kFileMagic, 8);
  const std::uint32_t version = kFormatVersion, record_size = sizeof(JournalRecord);
  std::memcpy(header + 8, &version, 4);
  std::memcpy(header + 12, &record_size, 4);
  static_assert(kHeaderBytes >= 16 + sizeof options.scene_fingerprint);
  std::memcpy(header + 16, options.scene_fingerprint.data(), options.scene_fingerprint.size());
  if (!write_all(options.sink.get(), fd, header, kHeaderBytes) || ::fdatasync(fd) != 0) {
    ::close(fd);
    return io_error(file.string() + ": cannot write the journal header: " + std::strerror(errno));
  }
  std::unique_ptr<JournalWriter> w(new JournalWriter(fd, options));
  w->path_ = file;
  w->good_bytes_ = static_cast<off_t>(kHeaderBytes);
  w->thread_ = std::thread([p = w.get()] { p->run(); });
  return w;
}

bool JournalWriter::append(const JournalRecord& record) {
  JournalRecord r = record;
  r.dropped_before = dropped_since_last_;
  if (!queue_.push(r)) {
    ++dropped_since_last_;
    ++dropped_total_;
    return false;
  }
  dropped_since_last_ = 0;
  ++appended_;
  return true;
}

bool JournalWriter::wait_taken(std::chrono::nanoseconds limit) const {
  const auto until = std::chrono::steady_clock::now() + limit;
  while (taken_.load(std::memory_order_acquire) < appended_) {
    if (std::chrono::steady_clock::now() >= until) return false;
    std::this_thread::sleep_for(std::chrono::microseconds(50));
  }
  return true;
}

void JournalWriter::run() {
  make_current_thread_best_effort();  // the queue absorbs its delays; the cycle must not see them
  using Clock = std::chrono::steady_clock;
  auto last_sync = Clock::now();
  // A batch of encoded frames per write().
  std::vector<unsigned char> batch(kFrameBytes * 64);
  bool dirty = false;
  for (;;) {
    std::size_t n = 0;
    JournalRecord r;
    while (n < 64 && queue_.pop(&r)) encode(r, batch.data() + kFrameBytes * n++);
    if (n > 0 && write_failed_.load(std::memory_order_relaxed)) {
      lost_ += n;  // after a failure nothing more is written: the file stays readable
    } else if (n > 0) {
      if (write_all(options_.sink.get(), fd_, batch.data(), kFrameBytes * n)) {
        good_bytes_ += static_cast<off_t>(kFrameBytes * n);
        written_ += n;
        dirty = true;
      } else {
        // Disk full or I/O error: the loop is told first (it holds at its next cycle), then the
        // partial batch is cut off, keeping what was complete.
        write_failed_.store(true, std::memory_order_release);
        (void)::ftruncate(fd_, good_bytes_);
        ::fdatasync(fd_);
        lost_ += n;
      }
    }
    // After write_failed_: a waiter that sees the records taken sees the failure too.
    if (n > 0) taken_.fetch_add(n, std::memory_order_release);
    const auto now = Clock::now();
    if (dirty && now - last_sync >= std::chrono::milliseconds(options_.fsync_interval_ms)) {
      ::fdatasync(fd_);
      last_sync = now;
      dirty = false;
    }
    if (n == 0) {
      if (stop_.load(std::memory_order_acquire) && queue_.empty()) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  }
  if (dirty) ::fdatasync(fd_);
}

Status JournalWriter::close() {
  if (closed_) return {};
  closed_ = true;
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) thread_.join();
  const bool ok = ::close(fd_) == 0 && !write_failed_;
  fd_ = -1;
  return ok ? Status{}
            : io_error("journal: a write failed (disk full or I/O error); the " +
                       std::to_string(written_.load()) + " records before it are intact, " +
                       std::to_string(lost_.load()) + " were not written");

}

}  // namespace lftrack::loop
