#pragma once
// What the loop shows of each cycle to a watcher on another thread (the monitor page and the
// OpenIGTLink server read it through the cycle hub, watch/cycle_hub.hpp): every cycle's journal
// record, and, at most once per `image_period_ns` of the loop's clock, the pair the registration
// saw with the pose it found.
//
// The loop never waits for the watcher and allocates nothing here after allocate():
//  - records go through a bounded single-producer single-consumer queue; a full queue drops the
//    record and counts it (dropped_records());
//  - images go through a triple buffer: three preallocated slots, one the loop writes, one the
//    watcher reads, one in between. The loop hands a filled slot over with one atomic exchange
//    and the watcher takes the newest with another, so a slow watcher sees fewer images, never
//    an older one after a newer, and never a slot being written.
// Exactly one writer thread (the loop's) and one reader thread (the hub's).

#include <array>
#include <atomic>
#include <cstdint>
#include <vector>

#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/spsc_queue.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::loop {

inline constexpr int kMaxFeedViews = 2;

// One cycle's record, and whether its pose_delta is a registration of that cycle (the record
// leaves it zero otherwise).
struct FeedRecord {
  JournalRecord record;
  bool registered = false;
};

// One cycle's images as the registration saw them.
struct FeedImages {
  std::int64_t cycle = -1;
  std::int64_t cycle_start_ns = 0;  // the loop's clock
  bool registered = false;          // T_room_from_ct is this cycle's registration result
  tracking::Pose T_room_from_ct = tracking::Pose::Identity();
  int views = 0;
  std::array<tracking::Image<std::uint16_t>, kMaxFeedViews> raw;  // the whole detector, raw counts
  std::array<tracking::Image<float>, kMaxFeedViews> line_integral;  // the ROI window, ln(I0/I)
  std::array<tracking::Image<unsigned char>, kMaxFeedViews> valid;  // its usable pixels
};

class CycleFeed {
 public:
  // `record_capacity`: records the watcher may fall behind by before they are dropped.
  // `image_period_ns`: the shortest time between two published image sets (the loop's clock).
  explicit CycleFeed(std::size_t record_capacity = 1024, std::int64_t image_period_ns = 200'000'000);

  // Before the loop runs (TrackingLoop::create): sizes the image slots for the source's frames
  // (`pair`, as open() sized it) and the ROI windows. At most kMaxFeedViews views.
  Status allocate(const drivers::FramePair& pair, const std::vector<tracking::PixelWindow>& roi_windows);

  // ---- The loop's thread. Never blocks, never allocates. ----
  void publish_record(const JournalRecord& record, bool registered);
  // True when an image set is due at this cycle's start (the image period has passed).
  bool images_due(std::int64_t cycle_start_ns) const;
  // Copies the cycle's frames, line integrals, masks and pose into the free slot and hands it
  // over. Views beyond what allocate() sized are ignored.
  void publish_images(std::int64_t cycle, std::int64_t cycle_start_ns, bool registered,
                      const tracking::Pose& T_room_from_ct, const drivers::FramePair& pair,
                      const std::vector<tracking::Image<float>>& line_integral,
                      const std::vector<tracking::Image<unsigned char>>& valid);

  // ---- The watcher's thread. ----
  bool next_record(FeedRecord* record);
  // The newest image set if one was published since the last call, else null. The slot stays
  // the watcher's (the loop never writes it) until the next call.
  const FeedImages* newest_images();

  // Any thread.
  std::uint64_t dropped_records() const { return dropped_.load(std::memory_order_relaxed); }
  // Records queued for the watcher since the start (not those dropped); once the watcher has
  // taken this many, it has every record published before this call.
  std::uint64_t queued_records() const { return records_.pushed(); }
  std::int64_t image_period_ns() const { return image_period_ns_; }

 private:
  static constexpr int kFresh = 4;  // in middle_: the slot in between holds an unread image set

  SpscQueue<FeedRecord> records_;
  std::atomic<std::uint64_t> dropped_{0};
  std::int64_t image_period_ns_;
  std::array<FeedImages, 3> slots_;
  int back_ = 0;                // the loop's slot
  int front_ = 1;               // the watcher's slot
  std::atomic<int> middle_{2};  // the slot in between, | kFresh when unread
  std::int64_t last_images_ns_ = 0;
  bool any_images_ = false;
  bool allocated_ = false;
};

}  // namespace lftrack::loop
