// The cycle hub (cycle_hub.hpp): counts, transitions and traces from the loop's records, every
// record in order for watchers that need them all, and display images with the DRR at the pose.

#include "lftrack/watch/cycle_hub.hpp"

#include <gtest/gtest.h>

#include "watch_fixture.hpp"

namespace lftrack::watch {

using loop::CycleFeed;
using loop::TrackingState;
namespace {

using test_watch::HubOnFeed;
using test_watch::record;

TEST(CycleHub, CountsTransitionsAndTracesFromTheRecords) {
  HubOnFeed h;
  EXPECT_FALSE(h.hub->status().started);
  h.publish(record(0, TrackingState::kAlign, TrackingState::kTrack, 1.0, true));
  h.publish(record(1, TrackingState::kTrack, TrackingState::kTrack, 1.1, true));
  h.publish(record(2, TrackingState::kTrack, TrackingState::kHold, 9.0, false, 123456));
  h.publish(record(3, TrackingState::kHold, TrackingState::kHold, 9.0, false, 123456));
  auto r4 = record(4, TrackingState::kHold, TrackingState::kFault, 0, false, 654321);
  r4.record.overrun = 1;
  r4.record.skipped_periods = 2;
  r4.record.operator_refused = 3;
  h.publish(r4);
  const HubStatus s = h.hub->status();
  EXPECT_EQ(s.seq, 5u);
  EXPECT_EQ(s.counts.cycles, 5);
  EXPECT_EQ(s.counts.holds, 1);
  EXPECT_EQ(s.counts.faults, 1);
  EXPECT_EQ(s.counts.overruns, 1);
  EXPECT_EQ(s.counts.skipped_periods, 2);
  EXPECT_EQ(s.counts.operator_refused, 3);
  EXPECT_EQ(s.counts.commands, 2);
  ASSERT_EQ(s.transitions.size(), 3u);
  EXPECT_EQ(s.transitions[1].to, TrackingState::kHold);
  EXPECT_EQ(s.transitions[1].hold_id, 123456u);
  EXPECT_NE(s.transitions[1].reason.find("gate"), std::string::npos) << s.transitions[1].reason;
  const auto trace = h.hub->trace_after(1, 100);
  ASSERT_EQ(trace.size(), 3u) << "cycles 2, 3, 4";
  EXPECT_EQ(trace.front().cycle, 2);
  EXPECT_FLOAT_EQ(trace.front().offset[0], 9.0f);
  EXPECT_NEAR(trace.front().offset[5], 0.5f, 1e-5) << "degrees for display";
  EXPECT_EQ(h.hub->trace_after(-1, 2).size(), 2u) << "at most max, the newest";
  EXPECT_EQ(h.hub->trace_after(-1, 2).back().cycle, 4);
}

TEST(CycleHub, KeepsTheLastCyclesAndSaysWhatAWatcherMissed) {
  HubOnFeed h;  // trace 50 cycles, history 100 records
  for (std::uint64_t c = 0; c < 150; ++c) h.feed.publish_record(record(c, TrackingState::kTrack, TrackingState::kTrack, 0, false).record, true);
  h.publish(record(150, TrackingState::kTrack, TrackingState::kTrack, 0, false));
  std::uint64_t first = 0, skipped = 0;
  auto all = h.hub->records_after(0, 1000, &first, &skipped);
  EXPECT_EQ(all.size(), 100u);
  EXPECT_EQ(skipped, 51u) << "the records of cycles 0..50 (numbers 1..51) are forgotten";
  EXPECT_EQ(all.front().record.cycle, 51u);
  EXPECT_EQ(all.back().record.cycle, 150u);
  auto next = h.hub->records_after(150, 10, &first, &skipped);
  EXPECT_EQ(next.size(), 1u);
  EXPECT_EQ(next[0].record.cycle, 150u);
  EXPECT_EQ(skipped, 0u);
  EXPECT_TRUE(h.hub->records_after(151, 10, &first, &skipped).empty());
  EXPECT_EQ(h.hub->trace_after(-1, 1000).size(), 50u);
}

TEST(CycleHub, DrawsEachViewWithTheDrrAtThePose) {
  auto renderer = tracking::make_renderer("siddon", test::fixture_volume(), {});
  ASSERT_TRUE(renderer.ok());
  HubOnFeed h(std::shared_ptr<const tracking::DrrRenderer>(std::move(renderer).value()));
  h.publish_images(7);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (!h.hub->images() && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  auto images = h.hub->images();
  ASSERT_TRUE(images);
  EXPECT_EQ(images->cycle, 7);
  ASSERT_EQ(images->views.size(), 2u);
  const DisplayView& a = images->views[0];
  EXPECT_EQ(a.name, "A");
  EXPECT_EQ(a.roi.rows, 24);
  EXPECT_EQ(a.roi.cols, 30);
  EXPECT_EQ(a.drr.rows, 24) << "the DRR in the ROI window";
  // The frame's ramp is windowed to the full grey range; the DRR shows the volume (not blank).
  EXPECT_EQ(*std::min_element(a.roi.pixels.begin(), a.roi.pixels.end()), 0);
  EXPECT_EQ(*std::max_element(a.roi.pixels.begin(), a.roi.pixels.end()), 255);
  EXPECT_GT(*std::max_element(a.drr.pixels.begin(), a.drr.pixels.end()), 100);
  EXPECT_EQ(a.thumbnail.rows, h.view.rows) << "a 40 x 48 detector needs no binning";
  EXPECT_EQ(a.roi_in_thumbnail[0], 4);
  EXPECT_EQ(a.roi_in_thumbnail[3], 30);
}

TEST(CycleHub, RefusesWhatItCannotWatch) {
  CycleFeed feed;
  HubOptions o;
  EXPECT_FALSE(CycleHub::start(&feed, o).ok()) << "no views";
  o.views = {test::fixture_view()};
  o.roi_windows = {{0, 0, 4, 4}};
  EXPECT_FALSE(CycleHub::start(nullptr, o).ok());
  o.render_share = 0;
  EXPECT_FALSE(CycleHub::start(&feed, o).ok());
  o.render_share = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(CycleHub::start(&feed, o).ok());
  o.render_share = 0.05;
  o.trace_cycles = -1;
  EXPECT_FALSE(CycleHub::start(&feed, o).ok());
}

}  // namespace
}  // namespace lftrack::watch
