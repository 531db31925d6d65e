#include "lftrack/host/journal.hpp"

#include "lftrack/host/realtime_setup.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <fstream>
#include <iterator>

#include "lftrack/host/crc32c.hpp"

namespace lftrack::host {
namespace {

constexpr char kFileMagic[8] = {'L', 'F', 'T', 'J', 'R', 'N', 'L', '1'};
constexpr std::uint32_t kFormatVersion = 1;
constexpr std::uint32_t kFrameMagic = 0x4A52464C;  // "LFRJ"
constexpr std::size_t kHeaderBytes = 32;
constexpr std::size_t kFrameBytes = 8 + sizeof(JournalRecord) + 4;

struct Frame {
  std::uint32_t magic = kFrameMagic;
  std::uint32_t size = sizeof(JournalRecord);
  JournalRecord record;
  std::uint32_t crc = 0;
};

void encode(const JournalRecord& r, unsigned char* out) {
  const std::uint32_t magic = kFrameMagic, size = sizeof(JournalRecord);
  std::memcpy(out, &magic, 4);
  std::memcpy(out + 4, &size, 4);
  std::memcpy(out + 8, &r, sizeof r);
  const std::uint32_t crc = crc32c(out + 8, sizeof r);
  std::memcpy(out + 8 + sizeof r, &crc, 4);
}

bool write_all(ssize_t (*write_call)(int, const void*, std::size_t), int fd, const unsigned char* p,
               std::size_t n) {
  while (n > 0) {
    const ssize_t w = write_call(fd, p, n);
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

Result<std::unique_ptr<JournalWriter>> JournalWriter::open(const std::filesystem::path& file,
                                                           const JournalOptions& options) {
  const int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return io_error(file.string() + ": cannot create journal: " + std::strerror(errno));
  unsigned char header[kHeaderBytes] = {};
  std::memcpy(header, kFileMagic, 8);
  const std::uint32_t version = kFormatVersion, record_size = sizeof(JournalRecord);
  std::memcpy(header + 8, &version, 4);
  std::memcpy(header + 12, &record_size, 4);
  if (!write_all(options.write_call, fd, header, kHeaderBytes) || ::fdatasync(fd) != 0) {
    ::close(fd);
    return io_error(file.string() + ": cannot write the journal header: " + std::strerror(errno));
  }
  std::unique_ptr<JournalWriter> w(new JournalWriter(fd, options));
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
      if (write_all(options_.write_call, fd_, batch.data(), kFrameBytes * n)) {
        good_bytes_ += static_cast<off_t>(kFrameBytes * n);
        written_ += n;
        dirty = true;
      } else {
        // Disk full or I/O error: cut the partial batch off, keep what was complete.
        (void)::ftruncate(fd_, good_bytes_);
        ::fdatasync(fd_);
        lost_ += n;
        write_failed_.store(true, std::memory_order_release);
      }
    }
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

Result<JournalContents> read_journal(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) return not_found(file.string() + ": cannot open journal");
  const std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)),
                                         std::istreambuf_iterator<char>());
  if (bytes.size() < kHeaderBytes || std::memcmp(bytes.data(), kFileMagic, 8) != 0)
    return invalid_argument(file.string() + ": not an lftrack journal");
  std::uint32_t version = 0, record_size = 0;
  std::memcpy(&version, bytes.data() + 8, 4);
  std::memcpy(&record_size, bytes.data() + 12, 4);
  if (version != kFormatVersion)
    return invalid_argument(file.string() + ": journal format version " + std::to_string(version) +
                            ", this lftrack reads version " + std::to_string(kFormatVersion));
  if (record_size != sizeof(JournalRecord))
    return invalid_argument(file.string() + ": journal records of " + std::to_string(record_size) +
                            " bytes, expected " + std::to_string(sizeof(JournalRecord)));
  JournalContents out;
  std::size_t pos = kHeaderBytes;
  while (pos < bytes.size()) {
    const std::size_t left = bytes.size() - pos;
    std::string problem;
    std::uint32_t magic = 0, size = 0, crc = 0;
    if (left < kFrameBytes) {
      problem = "a partial record of " + std::to_string(left) + " bytes";
    } else {
      std::memcpy(&magic, bytes.data() + pos, 4);
      std::memcpy(&size, bytes.data() + pos + 4, 4);
      std::memcpy(&crc, bytes.data() + pos + 8 + sizeof(JournalRecord), 4);
      if (magic != kFrameMagic || size != sizeof(JournalRecord))
        problem = "a record with a bad frame header";
      else if (crc32c(bytes.data() + pos + 8, sizeof(JournalRecord)) != crc)
        problem = "a record whose checksum does not match";
    }
    if (!problem.empty()) {
      if (left <= kFrameBytes) {  // the last frame: torn by a kill or a crash, ignored
        out.torn_tail_bytes = left;
        out.note = "ignored a torn tail: " + problem;
        break;
      }
      return invalid_argument(file.string() + ": " + problem + " at byte " + std::to_string(pos) +
                              " (not at the end: the journal is damaged)");
    }
    JournalRecord r;
    std::memcpy(&r, bytes.data() + pos + 8, sizeof r);
    out.records.push_back(r);
    pos += kFrameBytes;
  }
  return out;
}

}  // namespace lftrack::host
