#pragma once
// Frames from an archived sequence (frame_sequence.hpp), through the same loop as live
// detectors.
//
// Pacing: `realtime` replays at the recorded pace: the pair due at a requested exposure time is
// the last whose timestamp offset from the first pair is not later than the time since the first
// request, and acquire() waits (within its deadline) until the pair is due; frames are stamped
// with the loop's clock, shifted like the recording. Otherwise each request takes the next pair
// in order and acquire() waits for it however long the file system takes (a loop on a simulated
// clock; as fast as possible), stamped with the requested exposure time plus the view's offset
// within the recorded pair.
//
// A pair's files are read on a thread of the source's own, started by request_exposure(), into
// buffers sized by open(); acquire() copies them out. A missing, unreadable or wrong-sized
// frame makes the pair's acquire() return kFault and is counted by kind (counters()); after the
// last pair acquire() returns kDisconnected and exhausted() is true.

#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/drivers/frame_sequence.hpp"
#include "lftrack/drivers/frame_source.hpp"

namespace lftrack::drivers {

struct ReplayOptions {
  bool realtime = false;
};

struct ReplayCounters {
  std::int64_t pairs_delivered = 0;
  std::int64_t missing = 0;     // frames the index does not list, or whose file does not exist
  std::int64_t unreadable = 0;  // not a readable 16-bit TIFF/PNG
  std::int64_t wrong_size = 0;  // another size than the scene's detector
  std::int64_t late = 0;        // realtime: the next pair was not due by the deadline
};

class ReplayFrameSource final : public FrameSource {
 public:
  // `detectors`: the scene's detectors, in its order; each must appear in the sequence.
  ReplayFrameSource(FrameSequence sequence, std::vector<DetectorShape> detectors,
                    const ReplayOptions& options);
  ~ReplayFrameSource() override;

  Status open(FramePair* pair) override;
  void request_exposure(std::int64_t exposure_time_ns) override;
  DeviceStatus acquire(FramePair* pair, Deadline deadline) override;
  bool exhausted() const override;
  bool live() const override { return false; }  // recorded frames: the patient has gone
  void close() override;

  std::size_t pairs() const { return sequence_.pairs.size(); }
  const FrameSequence& sequence() const { return sequence_; }
  // The pair the last successful acquire() delivered (null before the first). On the loop's
  // thread only.
  const SequencePair* delivered() const { return delivered_; }
  // After the loop has stopped (not synchronised with a running acquire()).
  const ReplayCounters& counters() const { return counters_; }

 private:
  void read_loop();
  void load(std::size_t job);
  std::int64_t offset_ns(std::size_t pair) const;  // pair's start after the first pair's

  FrameSequence sequence_;
  std::vector<DetectorShape> detectors_;
  std::vector<std::size_t> column_;          // scene detector -> sequence detector
  std::vector<std::int64_t> pair_start_ns_;  // per pair: its earliest frame's timestamp
  ReplayOptions options_;
  ReplayCounters counters_;

  std::vector<tracking::Image<std::uint16_t>> loaded_;  // per scene detector
  std::vector<Status> loaded_status_;                   // per scene detector

  std::thread thread_;
  mutable std::mutex mutex_;
  std::condition_variable wake_, done_;
  std::size_t requested_ = 0;          // the pair to load next (== pairs(): past the end)
  std::size_t loaded_job_ = SIZE_MAX;  // the pair in loaded_
  std::int64_t requested_exposure_ns_ = 0;
  bool has_request_ = false, loading_ = false, stopping_ = false;
  std::size_t next_ = 0;  // the first pair not yet delivered
  bool started_ = false;
  std::int64_t first_request_ns_ = 0;
  bool exhausted_ = false;
  const SequencePair* delivered_ = nullptr;
};

}  // namespace lftrack::drivers
