#pragma once
// The cycle journal: one fixed-size record per cycle, appended to a file by a writer thread fed
// through a lock-free single-producer queue, so the cycle never waits on the disk.
//
// File layout (little-endian): a 32-byte header ("LFTJRNL1", format version, record size, the
// scene's 16-byte fingerprint or zeros), then
// one frame per record: u32 magic 0x4A52464C ("LFRJ"), u32 payload size, the payload (a
// JournalRecord), u32 CRC-32C of the payload. Version 6 (written now) has 576-byte records;
// version 5 (still read) had 392, the prefix up to `imaging`, version 4 (still read) had 352, the prefix up
// to `frames_arrived_ns`, version 3 296, the prefix up to `true_target_residual`, version 2 264, the prefix
// up to `operator_refused_by_reason`, and version 1 256, the prefix up to `hold_id`. Fields a version lacks
// read as zero.
//
// Durability: the writer write()s records within a few milliseconds of the push, so they are
// in the kernel's page cache and survive the process being killed (kill -9) at any moment; it
// calls fdatasync() every `fsync_interval_ms` (default 1 s) and at close, which bounds what a
// power loss can take. A kill during a write() leaves a torn last frame; a power loss can leave
// zero-filled blocks at the end.
//
// Reading is offline (lftrack/records/journal_reader.hpp, in lftrack::records): the cycle only
// writes.

#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/loop/spsc_queue.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::loop {

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
  // Format version 2 on. The HOLD or FAULT this cycle ends in (0: neither): every entry into HOLD
  // or FAULT takes the next id, and an operator's resume or reset must name it.
  std::uint32_t hold_id = 0;
  std::uint8_t operator_command = 0;   // 1 + OperatorCommand the loop acted on this cycle; 0: none
  std::uint8_t operator_refusal = 0;   // OperatorRefusal of the last command refused this cycle; 0: none
  std::uint16_t operator_refused = 0;  // commands refused or discarded this cycle (stale, wrong id, ...),
                                       // saturating at 65535
  // BeamWithheld: why a cycle whose gate applied and that ends in TRACK kept the beam off (the
  // alignment, or the patient not in place); 0: it did not. In
  // version 2 since 2026-11-27, in a byte that was reserved (zero) before.
  std::uint8_t beam_withheld = 0;
  // Format version 3 on (in version 2 a reserved byte, zero): the first reason refused this cycle
  // (OperatorRefusal; 0: none).
  std::uint8_t operator_first_refusal = 0;
  std::uint8_t reserved[2] = {};
  // Format version 3 on: how many commands were refused this cycle for each reason (index:
  // OperatorRefusal; saturating at 65535), so that no reason is lost behind another.
  std::uint16_t operator_refused_by_reason[16] = {};
  // Format version 4 on. Simulation only (zeros otherwise, and where true_residual_mm is -1): the
  // target's true offset after correction, at the registration origin, room frame: where the
  // anatomy has it minus where the plan has it (mm), and the rotation vector from the plan's
  // orientation to the anatomy's (rad). tracking_accuracy.hpp reports it per axis.
  double true_target_residual[6] = {};
  // Format version 4 on: when the actuator acknowledged this cycle's command, on the loop's clock
  // (its command() returned; simulated clock: the command's deadline); 0 when none was sent.
  std::int64_t command_acked_ns = 0;
  // Format version 5 on, the real clock only (zeros on the simulated clock, whose cycle work takes
  // no time, in earlier journals, and for a link the cycle did not reach): the latency chain's
  // links on the loop's clock, between the exposure (frame_time_ns) and the acknowledgement
  // (command_acked_ns). latency_chain.hpp names the links.
  std::int64_t frames_arrived_ns = 0;   // the pair complete on the host: the frame source returned it
  std::int64_t preprocessed_ns = 0;     // both frames to line integrals
  std::int64_t registered_ns = 0;       // the registration and its verdict done
  std::int64_t gated_ns = 0;            // the control law and the safety gate decided
  std::int64_t command_written_ns = 0;  // the command handed to the actuator's driver
  // Format version 6 on: imaging on demand (imaging_on_demand.hpp). Zeros in earlier journals.
  std::uint8_t imaging = 0;          // 1 + ImagingReason: why this cycle took a pair (1: it did not)
  std::uint8_t surrogate_fault = 0;  // SurrogateFault at the cycle (model imaging only)
  std::uint8_t model_check = 0;      // 1 + CorrelationModel::Check of this cycle's pair; 0: none
  std::uint8_t model_flags = 0;   // bit 0: the model is ready; bit 1: it gave the control this cycle's offset
  std::uint32_t model_pairs = 0;  // the pairs the model is fitted on
  // The surrogate at the cycle (model imaging; 0 without a reading): its newest reading's time on
  // the loop's clock, amplitude and rate (per s).
  std::int64_t surrogate_time_ns = 0;
  double surrogate[2] = {};
  double model_prediction_mm[3] = {};  // the model's target position at that reading (room, mm), when ready
  double model_check_error_mm = 0;  // this cycle's check: the prediction's 3D distance from the registration
  double model_fit_rms_mm[3] = {};  // the model's fit, per room axis
  // Per room axis, the coefficients of 1, s', s'^2 and r' on the standardised surrogate
  // (CorrelationModel::coefficients): the model as it stands after this cycle.
  double model_coefficients[12] = {};
};
static_assert(std::is_trivially_copyable_v<JournalRecord>);

// Where the writer thread's bytes go. The journal's file itself by default; a disk that fills up
// or fails (the tests, the chaos soak) is a sink of their own, injected through JournalOptions.
// Called by open() for the header, then from the writer thread only; never from the cycle.
class JournalSink {
 public:
  virtual ~JournalSink() = default;
  // As write(2) on the journal's descriptor: the bytes written, or -1 with errno set.
  virtual ssize_t write(int fd, const void* data, std::size_t bytes) = 0;
};

struct JournalOptions {
  std::size_t queue_capacity = 4096;  // records; 6.8 minutes at 10 Hz of a stalled disk
  int fsync_interval_ms = 1000;
  // A journal is a record of treatment: open() refuses a file that exists, unless this is set;
  // even then it replaces only an earlier lftrack journal (a regular file, not through a link).
  bool overwrite = false;
  // Instead of refusing an existing file, take the next free name: NAME-2.EXT, NAME-3.EXT, ...
  // (for default, time-stamped names).
  bool add_suffix = false;
  // Where the bytes go (null: write(2) to the file); the writer keeps it while it runs.
  std::shared_ptr<JournalSink> sink = nullptr;
  // What the journal records the cycles of, written into the header's last 16 bytes (zeros:
  // not recorded): the session's scene fingerprint, so that an export can refuse a scene other
  // than the one the run used.
  std::array<std::uint8_t, 16> scene_fingerprint{};
};

// Whether a journal may be created at `file`: nothing there, or (overwrite) an earlier lftrack
// journal, a regular file not reached through a symbolic link. For checking options early;
// JournalWriter::open checks again.
Status check_journal_path(const std::filesystem::path& file, bool overwrite);

class JournalWriter {
 public:
  ~JournalWriter();
  // Creates the file (refused when anything is there, unless options.overwrite and it is an
  // earlier journal: then truncated), writes the header and starts the writer thread.
  // path() says which file it is (add_suffix may have chosen another name).
  static Result<std::unique_ptr<JournalWriter>> open(const std::filesystem::path& file,
                                                     const JournalOptions& options = {});
  // From the cycle: never blocks, never allocates. Returns false (and counts it) when the queue
  // is full.
  bool append(const JournalRecord& record);
  // Drains the queue, syncs and closes. Called by the destructor too.
  Status close();
  std::uint64_t written() const { return written_.load(); }
  // Records the queue accepted (append returned true), and records the writer has taken from
  // it and finished with (written, or lost after a failure). Both from the cycle's thread.
  std::uint64_t appended() const { return appended_; }
  std::uint64_t taken() const { return taken_.load(std::memory_order_acquire); }
  // Waits (polling, allocating nothing) until the writer has finished with every record
  // appended so far, or `limit` has passed; returns whether it has. Once it has, failed() says
  // whether any of them failed. The simulated clock calls it before each cycle, so that a disk
  // that fills up is seen at the next cycle's gate however the writer thread was scheduled.
  bool wait_taken(std::chrono::nanoseconds limit) const;
  const std::filesystem::path& path() const { return path_; }
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
  std::filesystem::path path_;
  JournalOptions options_;
  SpscQueue<JournalRecord> queue_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> written_{0};
  std::uint64_t appended_ = 0;
  std::atomic<std::uint64_t> taken_{0};
  std::atomic<bool> write_failed_{false};
  std::atomic<std::uint64_t> lost_{0};
  off_t good_bytes_ = 0;  // the file's length up to the last complete write
  std::uint32_t dropped_since_last_ = 0;
  std::uint64_t dropped_total_ = 0;
  bool closed_ = false;
};

}  // namespace lftrack::loop
