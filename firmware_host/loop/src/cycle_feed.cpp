#include "lftrack/loop/cycle_feed.hpp"

#include <algorithm>

namespace lftrack::loop {

CycleFeed::CycleFeed(std::size_t record_capacity, std::int64_t image_period_ns)
    : records_(record_capacity), image_period_ns_(image_period_ns) {}

Status CycleFeed::allocate(const drivers::FramePair& pair, const std::vector<tracking::PixelWindow>& roi_windows) {
  const std::size_t views = pair.frames.size();
  if (views == 0 || views > std::size_t(kMaxFeedViews) || roi_windows.size() != views)
    return invalid_argument("cycle feed: 1 to " + std::to_string(kMaxFeedViews) +
                            " views, each with its ROI window, are needed");
  for (FeedImages& slot : slots_) {
    slot.views = static_cast<int>(views);
    for (std::size_t v = 0; v < views; ++v) {
      const auto& frame = pair.frames[v].pixels;
      const tracking::PixelWindow& w = roi_windows[v];
      slot.raw[v] = tracking::Image<std::uint16_t>(frame.rows(), frame.cols());
      slot.line_integral[v] = tracking::Image<float>(w.rows, w.cols);
      slot.valid[v] = tracking::Image<unsigned char>(w.rows, w.cols);
    }
  }
  allocated_ = true;
  return {};
}

void CycleFeed::publish_record(const JournalRecord& record, bool registered) {
  if (!records_.push(FeedRecord{record, registered})) dropped_.fetch_add(1, std::memory_order_relaxed);
}

bool CycleFeed::images_due(std::int64_t cycle_start_ns) const {
  return allocated_ && (!any_images_ || cycle_start_ns - last_images_ns_ >= image_period_ns_);
}

namespace {

// Copies `from` into `to` when both have the same size (the slots were sized for these images);
// otherwise leaves `to` as it is and says so.
template <class T>
bool copy_same_size(const tracking::Image<T>& from, tracking::Image<T>* to) {
  if (from.rows() != to->rows() || from.cols() != to->cols()) return false;
  std::copy(from.pixels().begin(), from.pixels().end(), to->pixels().begin());
  return true;
}

}  // namespace

void CycleFeed::publish_images(std::int64_t cycle, std::int64_t cycle_start_ns, bool registered,
                               const tracking::Pose& T_room_from_ct, const drivers::FramePair& pair,
                               const std::vector<tracking::Image<float>>& line_integral,
                               const std::vector<tracking::Image<unsigned char>>& valid) {
  if (!allocated_) return;
  FeedImages& slot = slots_[std::size_t(back_)];
  bool complete = true;
  for (int v = 0; v < slot.views; ++v) {
    const auto i = std::size_t(v);
    complete = complete && i < pair.frames.size() && i < line_integral.size() && i < valid.size() &&
               copy_same_size(pair.frames[i].pixels, &slot.raw[i]) &&
               copy_same_size(line_integral[i], &slot.line_integral[i]) && copy_same_size(valid[i], &slot.valid[i]);
  }
  if (!complete) return;  // a pair of another size than open() gave: nothing to show
  slot.cycle = cycle;
  slot.cycle_start_ns = cycle_start_ns;
  slot.registered = registered;
  slot.T_room_from_ct = T_room_from_ct;
  // Hand the slot over; the one in between (read or not) becomes the loop's next slot.
  back_ = middle_.exchange(back_ | kFresh, std::memory_order_acq_rel) & ~kFresh;
  last_images_ns_ = cycle_start_ns;
  any_images_ = true;
}

bool CycleFeed::next_record(FeedRecord* record) { return records_.pop(record); }

const FeedImages* CycleFeed::newest_images() {
  if ((middle_.load(std::memory_order_acquire) & kFresh) == 0) return nullptr;
  front_ = middle_.exchange(front_, std::memory_order_acq_rel) & ~kFresh;
  return &slots_[std::size_t(front_)];
}

}  // namespace lftrack::loop
