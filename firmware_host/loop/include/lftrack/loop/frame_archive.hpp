#pragma once
// Archiving the frames themselves, alongside the journal, in the format the replay source reads
// (drivers/frame_sequence.hpp: index.csv plus one uncompressed 16-bit TIFF per frame).
//
// The cycle copies its pair into one of a fixed set of preallocated slots and hands the slot's
// number to a writer thread through a lock-free single-producer queue; the writer writes the
// files, then their index rows, and returns the slot. append() never blocks and never allocates:
// when every slot is waiting for the disk the pair is dropped and counted (the index then lacks
// that pair; the journal still has the cycle). A frame's index row is written only after its
// file is complete, and the index is flushed after every pair, so after a crash every listed
// frame is whole (a torn last index line is ignored by the reader).

#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/drivers/frame_sequence.hpp"
#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/loop/spsc_queue.hpp"
#include "lftrack/tracking/pose.hpp"

namespace lftrack::loop {

struct FrameArchiveOptions {
  int slots = 16;              // pairs that may wait for the disk (1.6 s at 10 Hz)
  bool with_actuator = false;  // also write actuator.csv (the read-back at each pair)
  // An archive is a record: open() refuses a directory that holds anything, unless this is set
  // and the directory holds an earlier lftrack archive (index.csv, actuator.csv, frames/ of TIFFs
  // and nothing else), which is then removed first so no stale frame is mixed with the new ones.
  bool overwrite = false;
};

// Whether FrameArchive::open may write into `directory` (FrameArchiveOptions::overwrite), removing
// nothing: for checking options before anything is created.
Status check_archive_directory(const std::filesystem::path& directory, bool overwrite);

class FrameArchive {
 public:
  ~FrameArchive();
  // Creates `directory` (absent or empty; see FrameArchiveOptions::overwrite) and starts the
  // writer. `detectors` names and sizes the frames, in the pairs' order.
  static Result<std::unique_ptr<FrameArchive>> open(const std::filesystem::path& directory,
                                                    const std::vector<drivers::DetectorShape>& detectors,
                                                    const FrameArchiveOptions& options = {});
  // From the cycle: copies `pair` (numbered `pair_index`, e.g. the cycle) and the actuator's
  // read-back travel at its exposure (null: none this cycle) for writing. Returns false, and
  // counts the pair dropped, when no slot is free.
  bool append(std::int64_t pair_index, const drivers::FramePair& pair,
              const tracking::Vector6d* actuator_travel = nullptr);
  // Waits (polling, allocating nothing) until a slot is free for the next append, or `limit` has
  // passed; returns whether one is. The simulated clock calls it before each cycle: there the
  // cycles come without the period in which the writer empties slots on the real one, and a
  // starved writer must not cost the archive pairs that the real clock would have kept.
  bool wait_for_slot(std::chrono::nanoseconds limit) const;
  // Writes what is queued and closes the index. Called by the destructor too.
  Status close();
  std::uint64_t pairs_written() const { return written_.load(); }
  std::uint64_t pairs_dropped() const { return dropped_; }

 private:
  struct Slot {
    std::int64_t pair_index = 0;
    drivers::FramePair pair;
    bool has_actuator = false;
    double actuator_travel[6] = {};
  };
  FrameArchive(const std::filesystem::path& directory, const std::vector<drivers::DetectorShape>& detectors,
               const FrameArchiveOptions& options);
  void run();
  Status write_slot(const Slot& slot);

  std::string directory_text_;
  std::vector<std::string> names_;
  bool with_actuator_ = false;
  std::vector<Slot> slots_;
  SpscQueue<std::uint32_t> filled_;  // cycle -> writer
  SpscQueue<std::uint32_t> free_;    // writer -> cycle
  drivers::SequenceIndexWriter index_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> written_{0};
  std::atomic<bool> write_failed_{false};
  std::string first_error_;  // the writer's first failure (read after join)
  std::uint64_t dropped_ = 0;
  bool closed_ = false;
};

}  // namespace lftrack::loop
