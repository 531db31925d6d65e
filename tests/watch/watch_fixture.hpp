#pragma once
// What the watch tests share: a cycle feed with a hub on it, as a loop of two views over the
// renderer fixture would feed it, and records written the way the loop writes them.

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <thread>
#include <vector>

#include "fixtures.hpp"
#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/watch/cycle_hub.hpp"
#include "lftrack/watch/page_operator.hpp"

namespace lftrack::watch::test_watch {

// One cycle's record: state `to` after `from`, a registered offset of `tx` mm (and 0.5 degree
// about z), a correction sent when `command`.
inline loop::FeedRecord record(std::uint64_t cycle, loop::TrackingState from, loop::TrackingState to,
                               double tx, bool command, std::uint32_t hold_id = 0) {
  loop::FeedRecord f;
  loop::JournalRecord& r = f.record;
  r.cycle = cycle;
  r.cycle_start_ns = std::int64_t(cycle) * 100'000'000;
  r.frame_time_ns[0] = r.frame_time_ns[1] = r.cycle_start_ns;
  r.previous_state = static_cast<std::uint8_t>(from);
  r.state = static_cast<std::uint8_t>(to);
  if (to != from) r.event = 1 + static_cast<std::uint8_t>(loop::TrackingEvent::kGate);
  r.gate_reason =
      to == loop::TrackingState::kHold ? static_cast<std::uint8_t>(loop::GateReason::kStepTooLarge) : 0;
  r.hold_id = hold_id;
  r.pose_delta[0] = tx;
  r.pose_delta[5] = 0.5 * 3.14159265358979 / 180;
  r.similarity[0] = 0.5;
  r.similarity[1] = 0.6;
  r.registration_ms = 12.5;
  r.true_residual_mm = 0.2;
  if (command) {
    r.command_sent = 1;
    r.command[1] = -tx;
  }
  f.registered = true;
  return f;
}

struct HubOnFeed {
  loop::CycleFeed feed{4096, 0};
  std::unique_ptr<CycleHub> hub;
  tracking::XrayView view = test::fixture_view();
  std::vector<tracking::PixelWindow> windows{{4, 6, 24, 30}, {0, 0, 40, 48}};

  explicit HubOnFeed(std::shared_ptr<const tracking::DrrRenderer> renderer = nullptr) {
    HubOptions o;
    o.scene = "watch test";
    tracking::XrayView a = view, b = view;
    a.name = "A";
    b.name = "B";
    o.views = {a, b};
    o.roi_windows = windows;
    o.nominal_T_room_from_ct = tracking::Pose::Identity();
    o.registration_origin_room_mm = Eigen::Vector3d(1, 2, 3);
    o.renderer = std::move(renderer);
    o.trace_cycles = 50;
    o.record_history = 100;
    auto started = CycleHub::start(&feed, o);
    EXPECT_TRUE(started.ok()) << started.status().message();
    hub = std::move(started).value();
  }
  // Publishes and waits until the hub has absorbed it (at most 2 s).
  void publish(const loop::FeedRecord& f) {
    feed.publish_record(f.record, f.registered);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(2);
    while (hub->status().last.record.cycle != f.record.cycle || !hub->status().started) {
      if (std::chrono::steady_clock::now() > deadline) {
        ADD_FAILURE() << "the hub did not take cycle " << f.record.cycle;
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  }
  // Publishes a pair of frames as the loop would, for the hub to draw.
  void publish_images(std::int64_t cycle) {
    drivers::FramePair pair;
    for (int v = 0; v < 2; ++v)
      pair.frames.push_back({tracking::Image<std::uint16_t>(view.rows, view.cols, 1000), 0, 0});
    if (!images_allocated) {
      ASSERT_TRUE(feed.allocate(pair, windows).ok());
    }
    images_allocated = true;
    std::vector<tracking::Image<float>> li;
    std::vector<tracking::Image<unsigned char>> valid;
    for (const auto& w : windows) {
      li.emplace_back(w.rows, w.cols);
      for (int r = 0; r < w.rows; ++r)
        for (int c = 0; c < w.cols; ++c) li.back().at(r, c) = float(r + c);
      valid.emplace_back(w.rows, w.cols, 1);
    }
    feed.publish_images(cycle, cycle * 100'000'000, true, tracking::Pose::Identity(), pair, li, valid);
  }
  bool images_allocated = false;
};

// A loop polling every millisecond on its own thread, as the real one polls every cycle.
struct PollingLoop {
  PageOperator* page;
  loop::OperatorView view;
  std::atomic<bool> stop{false};
  std::vector<loop::OperatorPoll> polls;
  std::mutex mutex;
  std::thread thread;
  explicit PollingLoop(PageOperator* p, loop::OperatorView v) : page(p), view(v) {
    thread = std::thread([this] {
      while (!stop) {
        loop::OperatorPoll poll;
        page->poll(view, &poll);
        if (poll.command != loop::OperatorCommand::kNone || poll.refused > 0) {
          std::lock_guard<std::mutex> lock(mutex);
          polls.push_back(poll);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      }
    });
  }
  // Whether a poll journaled this refusal (as its last one) within `wait`.
  bool saw(loop::OperatorRefusal why, std::chrono::milliseconds wait = std::chrono::milliseconds(2000)) {
    const auto deadline = std::chrono::steady_clock::now() + wait;
    do {
      {
        std::lock_guard<std::mutex> lock(mutex);
        for (const loop::OperatorPoll& p : polls)
          if (p.last_refusal == why) return true;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    } while (std::chrono::steady_clock::now() < deadline);
    return false;
  }
  ~PollingLoop() {
    stop = true;
    thread.join();
  }
};

}  // namespace lftrack::watch::test_watch
