#include "lftrack/watch/cycle_hub.hpp"

#include <algorithm>
#include <cmath>

#include "display_images.hpp"
#include "lftrack/loop/allocation_counter.hpp"
#include "lftrack/loop/realtime_setup.hpp"

namespace lftrack::watch {

using loop::CycleFeed;
using loop::exclude_this_thread_from_allocation_count;
using loop::FeedImages;
using loop::FeedRecord;
using loop::GateReason;
using loop::JournalRecord;
using loop::kMaxFeedViews;
using loop::make_current_thread_best_effort;
using loop::TrackingEvent;
using loop::TrackingState;

namespace {

// Why the loop entered the state a record ends in: its event, and the gate's reason for a gate
// decision.
std::string transition_reason(const JournalRecord& r) {
  if (r.event == 0) return "";
  const auto event = static_cast<TrackingEvent>(r.event - 1);
  if (event == TrackingEvent::kGate) return std::string("gate: ") + to_string(static_cast<GateReason>(r.gate_reason));
  std::string reason = to_string(event);
  if (event == TrackingEvent::kAlignFailed || event == TrackingEvent::kDeviceFault)
    reason += std::string(": ") + to_string(static_cast<GateReason>(r.gate_reason));
  return reason;
}

TracePoint trace_point(const FeedRecord& f) {
  const JournalRecord& r = f.record;
  TracePoint p;
  p.cycle = static_cast<std::int64_t>(r.cycle);
  p.registered = f.registered;
  for (int i = 0; i < 3; ++i) {
    p.offset[std::size_t(i)] = static_cast<float>(r.pose_delta[i]);
    p.offset[std::size_t(i + 3)] = static_cast<float>(tracking::rad_to_deg(r.pose_delta[i + 3]));
  }
  p.true_residual_mm = static_cast<float>(r.true_residual_mm);
  p.similarity = {static_cast<float>(r.similarity[0]), static_cast<float>(r.similarity[1])};
  p.registration_ms = static_cast<float>(r.registration_ms);
  p.state = r.state;
  p.command_sent = r.command_sent != 0;
  return p;
}

}  // namespace

CycleHub::CycleHub(CycleFeed* feed, HubOptions options) : feed_(feed), options_(std::move(options)) {}

Result<std::unique_ptr<CycleHub>> CycleHub::start(CycleFeed* feed, HubOptions options) {
  if (feed == nullptr) return invalid_argument("cycle hub: no feed");
  if (options.views.empty() || options.views.size() > std::size_t(kMaxFeedViews) ||
      options.roi_windows.size() != options.views.size())
    return invalid_argument("cycle hub: 1 or 2 views, each with its ROI window");
  if (options.trace_cycles < 1 || options.record_history < 1 || options.image_max_side_px < 16 ||
      options.thumbnail_max_side_px < 16 || !(options.render_share > 0 && options.render_share <= 1))
    return invalid_argument("cycle hub: trace, history, image sizes and render share out of range");
  std::unique_ptr<CycleHub> hub(new CycleHub(feed, std::move(options)));
  hub->thread_ = std::thread([h = hub.get()] { h->run(); });
  return hub;
}

CycleHub::~CycleHub() { stop(); }

void CycleHub::stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_.store(true);
  }
  news_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void CycleHub::run() {
  make_current_thread_best_effort();  // a watcher never competes with the cycle
  exclude_this_thread_from_allocation_count();   // nor counts as its allocations
  while (!stop_.load()) {
    bool any = false;
    FeedRecord r;
    while (feed_->next_record(&r)) {
      absorb(r);
      any = true;
    }
    if (const FeedImages* images = feed_->newest_images()) {
      if (std::chrono::steady_clock::now() >= next_render_) {
        make_display(*images);
        any = true;
      }
    }
    if (any) news_.notify_all();
    std::unique_lock<std::mutex> lock(mutex_);
    news_.wait_for(lock, std::chrono::milliseconds(4), [&] { return stop_.load(); });
  }
}

void CycleHub::absorb(const FeedRecord& f) {
  const JournalRecord& r = f.record;
  std::lock_guard<std::mutex> lock(mutex_);
  HubStatus& s = status_;
  s.started = true;
  ++s.seq;
  s.last = f;
  HubCounts& n = s.counts;
  ++n.cycles;
  if (r.state != r.previous_state) {
    if (r.state == static_cast<std::uint8_t>(TrackingState::kHold)) ++n.holds;
    if (r.state == static_cast<std::uint8_t>(TrackingState::kFault)) ++n.faults;
    HubTransition t;
    t.cycle = static_cast<std::int64_t>(r.cycle);
    t.from = static_cast<TrackingState>(r.previous_state);
    t.to = static_cast<TrackingState>(r.state);
    t.reason = transition_reason(r);
    t.hold_id = r.hold_id;
    s.transitions.push_back(std::move(t));
    if (s.transitions.size() > std::size_t(options_.transitions_kept)) s.transitions.erase(s.transitions.begin());
  }
  n.overruns += r.overrun;
  n.skipped_periods += r.skipped_periods;
  n.operator_refused += r.operator_refused;
  n.commands += r.command_sent;
  n.records_dropped = feed_->dropped_records();
  trace_.push_back(trace_point(f));
  while (trace_.size() > std::size_t(options_.trace_cycles)) trace_.pop_front();
  history_.push_back(f);
  while (history_.size() > std::size_t(options_.record_history)) history_.pop_front();
}

void CycleHub::make_display(const FeedImages& images) {
  const auto started = std::chrono::steady_clock::now();
  auto display = std::make_shared<DisplayImages>();
  display->cycle = images.cycle;
  display->registered = images.registered;
  for (int v = 0; v < images.views; ++v) {
    const auto i = std::size_t(v);
    DisplayView out;
    out.name = options_.views[i].name;
    const tracking::PixelWindow& w = options_.roi_windows[i];
    out.bin = bin_for(w.rows, w.cols, options_.image_max_side_px);
    out.roi = windowed_grey(images.line_integral[i].view(), images.valid[i].view(), out.bin);
    if (options_.renderer) {
      tracking::Image<float> drr(w.rows, w.cols);
      tracking::Image<unsigned char> valid(w.rows, w.cols);
      tracking::RenderExtras extras;
      extras.valid = valid.view();
      if (options_.renderer->render(images.T_room_from_ct, options_.views[i], w, drr.view(), &extras).ok())
        out.drr = windowed_grey(drr.view(), valid.view(), out.bin);
    }
    int thumb_bin = 1;
    out.thumbnail = raw_thumbnail(images.raw[i], options_.thumbnail_max_side_px, &thumb_bin);
    out.roi_in_thumbnail = {w.row0 / thumb_bin, w.col0 / thumb_bin, w.rows / thumb_bin, w.cols / thumb_bin};
    display->views.push_back(std::move(out));
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  display->render_ms = 1e3 * seconds;
  next_render_ = std::chrono::steady_clock::now() +
                 std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                     std::chrono::duration<double>(seconds / options_.render_share));
  std::lock_guard<std::mutex> lock(mutex_);
  display->seq = ++status_.images_seq;
  images_ = std::move(display);
}

bool CycleHub::wait_for_news(std::uint64_t seen_seq, std::uint64_t seen_images,
                             std::chrono::milliseconds timeout) const {
  std::unique_lock<std::mutex> lock(mutex_);
  return news_.wait_for(lock, timeout, [&] {
    return stop_.load() || status_.seq != seen_seq || status_.images_seq != seen_images;
  }) && !stop_.load();
}

std::uint64_t CycleHub::catch_up(std::chrono::milliseconds timeout) const {
  const std::uint64_t queued = feed_->queued_records();
  std::unique_lock<std::mutex> lock(mutex_);
  news_.wait_for(lock, timeout, [&] { return stop_.load() || status_.seq >= queued; });
  return status_.seq;
}

HubStatus CycleHub::status() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return status_;
}

std::vector<TracePoint> CycleHub::trace_after(std::int64_t after_cycle, std::size_t max) const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<TracePoint> out;
  auto it = std::upper_bound(trace_.begin(), trace_.end(), after_cycle,
                             [](std::int64_t c, const TracePoint& p) { return c < p.cycle; });
  const std::size_t available = std::size_t(std::distance(it, trace_.end()));
  if (available > max) it += static_cast<std::ptrdiff_t>(available - max);
  out.assign(it, trace_.end());
  return out;
}

std::vector<FeedRecord> CycleHub::records_after(std::uint64_t after_seq, std::size_t max, std::uint64_t* first_seq,
                                                std::uint64_t* skipped) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const std::uint64_t oldest = status_.seq - history_.size() + 1;  // the number of history_.front()
  const std::uint64_t from = std::max(after_seq + 1, oldest);
  *skipped = from - (after_seq + 1);
  *first_seq = from;
  std::vector<FeedRecord> out;
  for (std::uint64_t n = from; n <= status_.seq && out.size() < max; ++n) out.push_back(history_[n - oldest]);
  return out;
}

std::shared_ptr<const DisplayImages> CycleHub::images() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return images_;
}

}  // namespace lftrack::watch
