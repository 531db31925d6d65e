#pragma once
// The cycle journal: one fixed-size record per cycle, appended to a file by a writer thread fed
// through a lock-free single-producer queue, so the cycle never waits on the disk.
//
// File layout (little-endian): a 32-byte header ("LFTJRNL1", format version, record size), then
// one frame per record: u32 magic 0x4A52464C ("LFRJ"), u32 payload size, the payload (a
// JournalRecord), u32 CRC-32C of the payload.
//
// Durability: the writer write()s records within a few milliseconds of the push, so they are
// in the kernel's page cache and survive the process being killed (kill -9) at any moment; it
// calls fdatasync() every `fsync_interval_ms` (default 1 s) and at close, which bounds what a
// power loss can take. A kill during a write() leaves a torn last frame; the reader detects it
// (short frame, bad magic or CRC), ignores it and says so.

#include <unistd.h>

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/host/spsc_queue.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::host {

// One cycle. Plain data; times are CLOCK_MONOTONIC nanoseconds.
struct JournalRecord {
  std::uint64_t cycle = 0;
  std::int64_t cycle_start_ns = 0;
  std::int64_t frame_time_ns[2] = {0, 0};
  std::uint32_t frame_sequence[2] = {0, 0};
  std::uint32_t dropped_before = 0;  // records the queue could not take since the last one
  std::uint32_t evaluations = 0;
  double pose_delta[6] = {};  // registered pose: delta from nominal (mm, rad)
  double similarity[4] = {};  // per view
  double registration_ms = 0;
  double command[6] = {};        // correction sent this cycle (mm, rad); zero if none
  double readback[6] = {};       // actuator read-back (mm, rad)
  double true_residual_mm = -1;  // simulation only: the true patient offset after correction
  std::uint8_t state = 0;        // TrackingState after this cycle
  std::uint8_t previous_state = 0;
  std::uint8_t gate_decision = 0;  // GateDecision
  std::uint8_t gate_reason = 0;    // GateReason
  std::uint8_t command_sent = 0;
  std::uint8_t beam_permit = 0;
  std::uint8_t overrun = 0;  // this cycle started late (missed periods were skipped)
  std::uint8_t event = 0;    // 1 + TrackingEvent that changed the state this cycle; 0: none
  std::uint32_t skipped_periods = 0;
  std::uint32_t reserved2 = 0;
};
static_assert(std::is_trivially_copyable_v<JournalRecord>);

struct JournalOptions {
  std::size_t queue_capacity = 4096;  // records; 6.8 minutes at 10 Hz of a stalled disk
  int fsync_interval_ms = 1000;
  // The write(2) the writer thread calls: the kernel's, or a fault injector in tests (a disk
  // that fills up, an I/O error).
  ssize_t (*write_call)(int fd, const void* data, std::size_t bytes) = &::write;
};

class JournalWriter {
 public:
  ~JournalWriter();
  // Creates (truncates) the file, writes the header and starts the writer thread.
  static Result<std::unique_ptr<JournalWriter>> open(const std::filesystem::path& file,
                                                     const JournalOptions& options = {});
  // From the cycle: never blocks, never allocates. Returns false (and counts it) when the queue
  // is full.
  bool append(const JournalRecord& record);
  // Drains the queue, syncs and closes. Called by the destructor too.
  Status close();
  std::uint64_t written() const { return written_.load(); }
  // True once a write has failed (disk full, I/O error). The writer then truncates the file to
  // its last complete record and writes nothing more, so everything written before stays
  // readable; the loop holds (safety gate: "journal write failed"). Any thread may ask.
  bool failed() const { return write_failed_.load(std::memory_order_acquire); }
  std::uint64_t lost() const { return lost_.load(); }  // records not written after the failure
  std::uint64_t dropped() const { return dropped_total_; }

 private:
  JournalWriter(int fd, const JournalOptions& options);
  void run();

  int fd_ = -1;
  JournalOptions options_;
  SpscQueue<JournalRecord> queue_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> written_{0};
  std::atomic<bool> write_failed_{false};
  std::atomic<std::uint64_t> lost_{0};
  off_t good_bytes_ = 0;  // the file's length up to the last complete write
  std::uint32_t dropped_since_last_ = 0;
  std::uint64_t dropped_total_ = 0;
  bool closed_ = false;
};

struct JournalContents {
  std::vector<JournalRecord> records;
  std::size_t torn_tail_bytes = 0;  // an incomplete or damaged last frame, ignored
  std::string note;                 // what was wrong at the tail, if anything
};

// Reads every complete record. Fails for a file that is not a journal (header), of another
// version or record size; a damaged frame before the last is an error, a damaged last one is
// reported as a torn tail.
Result<JournalContents> read_journal(const std::filesystem::path& file);

}  // namespace lftrack::host
