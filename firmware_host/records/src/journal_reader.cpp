// The journal's reader (journal_reader.hpp): checks every frame, resynchronises after damage, and
// reports bad spans, gaps and repeats instead of failing on the first bad byte.

#include "lftrack/records/journal_reader.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstddef>
#include <cstring>
#include <iterator>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/loop/crc32c.hpp"
#include "lftrack/loop/journal_format.hpp"

namespace lftrack::records {

using loop::crc32c;
using loop::JournalRecord;
using namespace loop::journal_format;  // NOLINT(google-build-using-namespace): the format's constants

namespace {

// Each version's records are a prefix of JournalRecord: `record_bytes` in the file, of which the
// first `field_bytes` hold fields (version 1's last 4 bytes were reserved); the rest reads as zero.
struct VersionLayout {
  std::size_t record_bytes, field_bytes;
};
constexpr std::uint32_t kFirstFormatVersion = 1;
constexpr VersionLayout kLayouts[] = {
    {256, offsetof(JournalRecord, hold_id)},                     // version 1
    {264, offsetof(JournalRecord, operator_refused_by_reason)},  // version 2
    {296, offsetof(JournalRecord, true_target_residual)},        // version 3
    {352, offsetof(JournalRecord, frames_arrived_ns)},           // version 4
    {392, offsetof(JournalRecord, imaging)},                     // version 5
    {sizeof(JournalRecord), sizeof(JournalRecord)},              // version 6
};
static_assert(std::size(kLayouts) == kFormatVersion - kFirstFormatVersion + 1, "a layout for every version read");
static_assert(kLayouts[0].field_bytes == 252 && kLayouts[1].field_bytes == 264 &&
                  kLayouts[2].field_bytes == 296 && kLayouts[3].field_bytes == 352 &&
                  kLayouts[4].field_bytes == 392 && sizeof(JournalRecord) == 576,
              "the layouts of versions 1 to 6 are fixed");
const VersionLayout& layout_of(std::uint32_t version) { return kLayouts[version - kFirstFormatVersion]; }
constexpr std::size_t kReadWindowBytes = std::size_t{1} << 20;

// A file read forward through a window of kReadWindowBytes: the bytes not yet consumed stay,
// the rest is read as needed. Works on anything read(2) reads: a file, a FIFO, a device.
class ReadWindow {
 public:
  explicit ReadWindow(int fd) : fd_(fd), buffer_(kReadWindowBytes) {}
  ~ReadWindow() { ::close(fd_); }
  ReadWindow(const ReadWindow&) = delete;
  ReadWindow& operator=(const ReadWindow&) = delete;

  // Reads until at least `n` (<= kReadWindowBytes) bytes are available or the file ends. False
  // on a read error (errno says which).
  bool want(std::size_t n);
  const unsigned char* data() const { return buffer_.data() + begin_; }
  std::size_t available() const { return end_ - begin_; }
  bool ended() const { return ended_; }
  void consume(std::size_t n) {
    begin_ += n;
    offset_ += n;
  }
  std::uint64_t offset() const { return offset_; }  // of data() in the file

 private:
  int fd_;
  std::vector<unsigned char> buffer_;
  std::size_t begin_ = 0, end_ = 0;
  std::uint64_t offset_ = 0;
  bool ended_ = false;
};

bool ReadWindow::want(std::size_t n) {
  if (available() >= n || ended_) return true;
  std::memmove(buffer_.data(), data(), available());
  end_ -= begin_;
  begin_ = 0;
  while (end_ < n) {
    const ssize_t got = ::read(fd_, buffer_.data() + end_, buffer_.size() - end_);
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) return false;
    if (got == 0) {
      ended_ = true;
      break;
    }
    end_ += static_cast<std::size_t>(got);
  }
  return true;
}

// The record size the header promises, after checking magic, version and size.
Result<std::size_t> read_header(ReadWindow* in, const std::string& name, std::uint32_t* version,
                                std::array<std::uint8_t, 16>* scene_fingerprint) {
  if (!in->want(kHeaderBytes)) return io_error(name + ": cannot read: " + std::strerror(errno));
  if (in->available() < kHeaderBytes || std::memcmp(in->data(), kFileMagic, 8) != 0)
    return invalid_argument(name + ": not an lftrack journal");
  std::uint32_t record_size = 0;
  std::memcpy(version, in->data() + 8, 4);
  std::memcpy(&record_size, in->data() + 12, 4);
  std::memcpy(scene_fingerprint->data(), in->data() + 16, scene_fingerprint->size());
  in->consume(kHeaderBytes);
  if (*version < kFirstFormatVersion || *version > kFormatVersion)
    return invalid_argument(name + ": journal format version " + std::to_string(*version) +
                            ", this lftrack reads versions " + std::to_string(kFirstFormatVersion) + " to " +
                            std::to_string(kFormatVersion));
  const std::size_t expected = layout_of(*version).record_bytes;
  if (record_size != expected)
    return invalid_argument(name + ": journal format version " + std::to_string(*version) +
                            " has records of " + std::to_string(expected) + " bytes, this file says " +
                            std::to_string(record_size));
  return expected;
}

enum class FrameCheck { kValid, kBadHeader, kBadChecksum, kCutShort };

const char* to_string(FrameCheck c) {
  switch (c) {
    case FrameCheck::kValid:
      return "valid";
    case FrameCheck::kBadHeader:
      return "no frame header (bad magic or size)";
    case FrameCheck::kBadChecksum:
      return "checksum mismatch";
    case FrameCheck::kCutShort:
      return "a frame cut short";
  }
  return "?";
}

// The frame that starts at `p`, of which `available` bytes exist.
FrameCheck check_frame(const unsigned char* p, std::size_t available, std::size_t record_bytes) {
  std::uint32_t magic = 0, size = 0, crc = 0;
  if (available >= 8) {
    std::memcpy(&magic, p, 4);
    std::memcpy(&size, p + 4, 4);
    if (magic != kFrameMagic || size != record_bytes) return FrameCheck::kBadHeader;
  }
  if (available < 8 + record_bytes + 4) return FrameCheck::kCutShort;
  std::memcpy(&crc, p + 8 + record_bytes, 4);
  return crc32c(p + 8, record_bytes) == crc ? FrameCheck::kValid : FrameCheck::kBadChecksum;
}

// How far past p[0] the next frame could start: the next frame magic in p[1, n), or a first
// byte of one that the window cuts off (unless the file ended there); n when there is none.
std::size_t bytes_to_next_candidate(const unsigned char* p, std::size_t n, bool file_ended) {
  unsigned char magic[4];
  std::memcpy(magic, &kFrameMagic, 4);
  std::size_t i = 1;
  while (i < n) {
    const void* hit = std::memchr(p + i, magic[0], n - i);
    if (hit == nullptr) return n;
    i = static_cast<std::size_t>(static_cast<const unsigned char*>(hit) - p);
    if (n - i < 4 ? !file_ended : std::memcmp(p + i, magic, 4) == 0) return i;
    ++i;
  }
  return n;
}

bool all_zero(const unsigned char* p, std::size_t n) {
  for (std::size_t i = 0; i < n; ++i)
    if (p[i] != 0) return false;
  return true;
}

// Checks each record's cycle against the highest one before it: the loop's next cycle is
// cycle + 1 + skipped_periods; more is a gap, the same or less a repeat.
class CycleCheck {
 public:
  void bad_span_seen() { bad_span_since_last_ = true; }
  void check(const JournalRecord& r, std::size_t index, JournalContents* out);

 private:
  bool any_ = false;
  std::uint64_t highest_ = 0;
  std::uint64_t expected_next_ = 0;
  bool bad_span_since_last_ = false;
};

void CycleCheck::check(const JournalRecord& r, std::size_t index, JournalContents* out) {
  if (any_ && r.cycle <= highest_) {
    out->repeats.push_back({r.cycle, highest_, index});
  } else {
    if (any_ && r.cycle > expected_next_) {
      JournalCycleGap gap;
      gap.after_cycle = highest_;
      gap.next_cycle = r.cycle;
      gap.missing_cycles = r.cycle - expected_next_;
      gap.dropped_before = r.dropped_before;
      gap.explained_by_drops = r.dropped_before >= 1 && r.dropped_before <= gap.missing_cycles;
      gap.after_bad_span = bad_span_since_last_;
      gap.record_index = index;
      out->gaps.push_back(gap);
    }
    any_ = true;
    highest_ = r.cycle;
    expected_next_ = r.cycle + 1 + r.skipped_periods;
  }
  bad_span_since_last_ = false;
}

// Appends a record, growing the vector by doubling but never past the record limit, so the cap
// also bounds the capacity.
void push_record(const JournalRecord& r, std::size_t max_records, std::vector<JournalRecord>* records) {
  if (records->size() == records->capacity())
    records->reserve(std::min(max_records, std::max<std::size_t>(1024, 2 * records->capacity())));
  records->push_back(r);
}

// Reserves room for every record a regular file can hold (up to the limit), so memory is the
// records and not twice that.
void reserve_for_file(int fd, std::size_t frame_bytes, std::size_t max_records,
                      std::vector<JournalRecord>* records) {
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) || st.st_size <= static_cast<off_t>(kHeaderBytes)) return;
  const auto frames = (static_cast<std::uint64_t>(st.st_size) - kHeaderBytes) / frame_bytes;
  records->reserve(static_cast<std::size_t>(std::min<std::uint64_t>(frames, max_records)));
}

std::string mib(std::uint64_t bytes) {
  return std::to_string(bytes >> 20) + " MiB";
}

// Walks the frames after the header: each valid one becomes a record, the bytes between valid
// frames become bad spans. Resynchronises after a bad frame on the next offset where a complete
// valid frame starts.
void read_frames(ReadWindow* in, std::uint32_t version, std::size_t record_bytes,
                 const JournalReadLimits& limits, JournalContents* out) {
  const std::size_t frame_bytes = 8 + record_bytes + 4;
  const std::size_t copy_bytes = layout_of(version).field_bytes;
  std::optional<JournalBadSpan> span;  // the bad span being scanned, from span->offset to here
  // Where the last non-zero byte of `span` lies, from its start (0: none yet). A write cut short
  // leaves less than a frame of data, then at most zeros; a full frame of data that fails its
  // check is damage, however near the end.
  std::uint64_t span_data_end = 0;
  std::uint64_t bad_bytes = 0;         // in earlier spans
  CycleCheck cycles;
  auto close_span = [&] {
    span->bytes = in->offset() - span->offset;
    bad_bytes += span->bytes;
    out->bad_spans.push_back(std::move(*span));
    span.reset();
    cycles.bad_span_seen();
  };
  for (;;) {
    if (!in->want(frame_bytes)) {
      const int error = errno;
      out->stopped = "a read error at byte " + std::to_string(in->offset() + in->available()) + ": " +
                     std::strerror(error) + "; the rest was not read";
      break;
    }
    if (in->available() == 0) break;
    const FrameCheck check = check_frame(in->data(), in->available(), record_bytes);
    if (check == FrameCheck::kValid) {
      if (span) close_span();
      if (out->records.size() >= limits.max_records) {
        out->stopped = "stopped at byte " + std::to_string(in->offset()) + ": the limit of " +
                       std::to_string(limits.max_records) + " records was reached; the rest was not read";
        break;
      }
      JournalRecord r;
      std::memcpy(&r, in->data() + 8, copy_bytes);
      cycles.check(r, out->records.size(), out);
      push_record(r, limits.max_records, &out->records);
      in->consume(frame_bytes);
      continue;
    }
    if (!span) {
      span = JournalBadSpan{in->offset(), 0, to_string(check), true};
      span_data_end = 0;
    }
    const std::size_t skip = bytes_to_next_candidate(in->data(), in->available(), in->ended());
    if (span->zeros) span->zeros = all_zero(in->data(), skip);
    for (std::size_t i = skip; i > 0; --i)
      if (in->data()[i - 1] != 0) {
        span_data_end = in->offset() - span->offset + i;
        break;
      }
    in->consume(skip);
    if (bad_bytes + (in->offset() - span->offset) > limits.max_bad_bytes) {
      close_span();
      out->stopped = "stopped at byte " + std::to_string(in->offset()) + " after " + mib(bad_bytes) +
                     " that are not records (the limit); the rest was not read";
      break;
    }
  }
  if (span) close_span();
  // A span that runs to the end and looks like what a crash leaves is a torn tail: at most a
  // frame cut short by a kill, then nothing but the zeros of blocks a power loss never wrote.
  if (out->stopped.empty() && !out->bad_spans.empty()) {
    const JournalBadSpan& last = out->bad_spans.back();
    if (last.offset + last.bytes == in->offset() && span_data_end < frame_bytes) {
      out->torn_tail_bytes = static_cast<std::size_t>(last.bytes);
      out->note = "ignored a torn tail: " + last.problem + (last.zeros ? " (zeros)" : "");
    }
  }
}

}  // namespace

bool JournalContents::damaged() const {
  const std::size_t torn_tails = torn_tail_bytes > 0 ? 1 : 0;
  if (bad_spans.size() > torn_tails || !repeats.empty() || !stopped.empty()) return true;
  return std::any_of(gaps.begin(), gaps.end(),
                     [](const JournalCycleGap& g) { return !g.explained_by_drops; });
}

Result<JournalContents> read_journal(const std::filesystem::path& file, const JournalReadLimits& limits) {
  // O_NONBLOCK: a FIFO with no writer opens at once (and then reads as empty) instead of
  // waiting for one; blocking reads from here on.
  const int fd = ::open(file.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd >= 0) {
    // A FIFO: wait a bounded time for its writer's first bytes, then read as a file.
    struct stat st {};
    if (::fstat(fd, &st) == 0 && S_ISFIFO(st.st_mode)) {
      pollfd p{fd, POLLIN, 0};
      if (::poll(&p, 1, 10'000) == 0) {
        ::close(fd);
        return io_error(file.string() + ": a FIFO with nothing to read within 10 s");
      }
    }
    ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) & ~O_NONBLOCK);
  }
  if (fd < 0 && errno == ENOENT) return not_found(file.string() + ": cannot open journal: no such file");
  if (fd < 0) return io_error(file.string() + ": cannot open journal: " + std::strerror(errno));
  ReadWindow in(fd);
  JournalContents out;
  auto record_bytes = read_header(&in, file.string(), &out.format_version, &out.scene_fingerprint);
  if (!record_bytes.ok()) return record_bytes.status();
  reserve_for_file(fd, 8 + *record_bytes + 4, limits.max_records, &out.records);
  read_frames(&in, out.format_version, *record_bytes, limits, &out);
  return out;
}

}  // namespace lftrack::records
