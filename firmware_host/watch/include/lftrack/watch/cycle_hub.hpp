#pragma once
// The loop as its watchers see it (the monitor page, the OpenIGTLink server): one thread of its
// own drains the loop's CycleFeed (cycle_feed.hpp) and keeps what they ask for:
//  - the newest record and its state, the gate's last decision and reason, counts of holds,
//    faults, overruns and refused operator commands, and the recent state transitions;
//  - a trace of the last `trace_cycles` cycles (registered offset, true residual in
//    simulation, per-view similarity, registration time) and the last `record_history` records
//    in order, numbered, for watchers that must see every cycle (OpenIGTLink);
//  - display images: each view's ROI as the registration saw it, the DRR at the pose it found
//    (rendered on this thread, never the loop's), and a thumbnail of the whole detector with
//    the ROI drawn on it, as 8-bit grey images.
// Watchers read under the hub's mutex, which the loop never takes: a slow or stalled watcher
// delays only itself. Rendering is rationed: after a render that took t, the next waits
// t / render_share (so the overlay takes at most that share of one core: a Siddon renderer of a
// second a view updates every 20 s, a light field every image period).

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/loop/cycle_feed.hpp"
#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::watch {

struct HubOptions {
  std::string scene;
  double period_ms = 100;
  std::vector<tracking::XrayView> views;           // room frame, the loop's order
  std::vector<tracking::PixelWindow> roi_windows;  // per view
  tracking::Pose nominal_T_room_from_ct = tracking::Pose::Identity();
  Eigen::Vector3d registration_origin_room_mm = Eigen::Vector3d::Zero();
  // Renders the overlay's DRR (the registration's renderer, called without a pool); null: none.
  std::shared_ptr<const tracking::DrrRenderer> renderer;
  int trace_cycles = 600;
  int record_history = 2048;
  int transitions_kept = 32;
  int image_max_side_px = 320;  // the ROI images are binned down to this
  int thumbnail_max_side_px = 200;
  double render_share = 0.05;
};

// One cycle in the traces (degrees for display).
struct TracePoint {
  std::int64_t cycle = 0;
  bool registered = false;
  std::array<float, 6> offset{};  // registered pose from nominal: mm, mm, mm, deg, deg, deg
  float true_residual_mm = -1;    // simulation only
  std::array<float, 2> similarity{};
  float registration_ms = 0;
  std::uint8_t state = 0;
  bool command_sent = false;
};

struct HubTransition {
  std::int64_t cycle = 0;
  loop::TrackingState from = loop::TrackingState::kIdle, to = loop::TrackingState::kIdle;
  std::string reason;
  std::uint32_t hold_id = 0;
};

struct HubCounts {
  std::int64_t cycles = 0, holds = 0, faults = 0, overruns = 0, skipped_periods = 0;
  std::int64_t operator_refused = 0, commands = 0;
  std::uint64_t records_dropped = 0;  // the feed's queue was full (the watchers fell behind)
};

struct HubStatus {
  bool started = false;  // a record has arrived
  std::uint64_t seq = 0;  // records absorbed so far (the newest record's number)
  loop::FeedRecord last;
  HubCounts counts;
  std::vector<HubTransition> transitions;  // oldest first
  std::uint64_t images_seq = 0;            // changes when new display images are ready
};

// 8-bit grey images, row-major, ready to draw.
struct GreyImage {
  int rows = 0, cols = 0;
  std::vector<std::uint8_t> pixels;
};

struct DisplayView {
  std::string name;
  GreyImage roi;        // the ROI's line integrals, windowed (bone bright)
  GreyImage drr;        // the DRR at the pose, same size; empty when not rendered
  GreyImage thumbnail;  // the whole detector, raw counts on a log scale
  std::array<int, 4> roi_in_thumbnail{};  // row0, col0, rows, cols
  int bin = 1;                            // ROI pixels per displayed pixel (per side)
};

struct DisplayImages {
  std::uint64_t seq = 0;
  std::int64_t cycle = 0;
  bool registered = false;
  double render_ms = 0;
  std::vector<DisplayView> views;
};

class CycleHub {
 public:
  // Starts the hub's thread on `feed` (which must outlive the hub). The thread drops from the
  // cycle's real-time priority to best effort: it never competes with the loop.
  static Result<std::unique_ptr<CycleHub>> start(loop::CycleFeed* feed, HubOptions options);
  ~CycleHub();
  void stop();

  const HubOptions& options() const { return options_; }
  // Waits until the hub has absorbed a record after `seen_seq` or made new images after
  // `seen_images`, or `timeout`; returns at once when stopped. True when something is new.
  bool wait_for_news(std::uint64_t seen_seq, std::uint64_t seen_images, std::chrono::milliseconds timeout) const;
  // When the loop has ended: waits until the hub has absorbed every record the feed had queued
  // at the call, or `timeout`. Returns the hub's seq then (status().seq), so that a server can
  // pass on the cycles up to it before it closes.
  std::uint64_t catch_up(std::chrono::milliseconds timeout) const;
  HubStatus status() const;
  // Trace points of cycles after `after_cycle`, oldest first, at most `max`.
  std::vector<TracePoint> trace_after(std::int64_t after_cycle, std::size_t max) const;
  // Records numbered after `after_seq`, oldest first (at most `max`); *skipped counts those
  // already forgotten (a watcher more than record_history behind).
  std::vector<loop::FeedRecord> records_after(std::uint64_t after_seq, std::size_t max,
                                              std::uint64_t* first_seq, std::uint64_t* skipped) const;
  std::shared_ptr<const DisplayImages> images() const;
  bool stopped() const { return stop_.load(); }

 private:
  explicit CycleHub(loop::CycleFeed* feed, HubOptions options);
  void run();
  void absorb(const loop::FeedRecord& r);
  void make_display(const loop::FeedImages& images);

  loop::CycleFeed* feed_;
  HubOptions options_;
  mutable std::mutex mutex_;
  mutable std::condition_variable news_;
  HubStatus status_;
  std::deque<TracePoint> trace_;
  std::deque<loop::FeedRecord> history_;  // numbered status_.seq - size + 1 ... status_.seq
  std::shared_ptr<const DisplayImages> images_;
  std::chrono::steady_clock::time_point next_render_{};
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace lftrack::watch
