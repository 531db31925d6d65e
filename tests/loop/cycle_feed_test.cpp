// The loop's feed to its watchers (cycle_feed.hpp): every record in order until the queue is
// full (then dropped and counted), images through a triple buffer that never hands the reader a
// slot being written nor an older image after a newer one, at most once per image period.

#include "lftrack/loop/cycle_feed.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <thread>

namespace lftrack::loop {
namespace {

drivers::FramePair pair_of(int rows, int cols, std::uint16_t value) {
  drivers::FramePair pair;
  for (int v = 0; v < 2; ++v) pair.frames.push_back({tracking::Image<std::uint16_t>(rows, cols, value), 0, 0});
  return pair;
}

TEST(CycleFeed, RecordsArriveInOrderAndAFullQueueDropsAndCounts) {
  CycleFeed feed(4);
  for (std::uint64_t c = 0; c < 6; ++c) {
    JournalRecord r;
    r.cycle = c;
    feed.publish_record(r, c % 2 == 0);
  }
  EXPECT_EQ(feed.dropped_records(), 2u) << "a queue of 4 takes 4 of 6";
  FeedRecord out;
  for (std::uint64_t c = 0; c < 4; ++c) {
    ASSERT_TRUE(feed.next_record(&out));
    EXPECT_EQ(out.record.cycle, c);
    EXPECT_EQ(out.registered, c % 2 == 0);
  }
  EXPECT_FALSE(feed.next_record(&out));
}

TEST(CycleFeed, ImagesAreTheNewestAndDueOncePerPeriod) {
  CycleFeed feed(16, /*image_period_ns=*/100);
  const std::vector<tracking::PixelWindow> windows{{2, 3, 4, 5}, {0, 0, 8, 8}};
  drivers::FramePair pair = pair_of(8, 8, 7);
  EXPECT_FALSE(feed.images_due(0)) << "nothing is due before allocate()";
  ASSERT_TRUE(feed.allocate(pair, windows).ok());
  std::vector<tracking::Image<float>> li{tracking::Image<float>(4, 5, 1.5f), tracking::Image<float>(8, 8, 2.5f)};
  std::vector<tracking::Image<unsigned char>> valid{tracking::Image<unsigned char>(4, 5, 1),
                                                    tracking::Image<unsigned char>(8, 8, 1)};
  EXPECT_EQ(feed.newest_images(), nullptr);
  EXPECT_TRUE(feed.images_due(0));
  tracking::Pose pose = tracking::Pose::Identity();
  pose.translation() << 1, 2, 3;
  feed.publish_images(10, 0, true, pose, pair, li, valid);
  EXPECT_FALSE(feed.images_due(50)) << "within the period";
  EXPECT_TRUE(feed.images_due(100));
  li[0].at(0, 0) = 9;
  feed.publish_images(11, 100, false, pose, pair, li, valid);
  const FeedImages* newest = feed.newest_images();
  ASSERT_NE(newest, nullptr);
  EXPECT_EQ(newest->cycle, 11) << "the newer of two unread sets";
  EXPECT_FALSE(newest->registered);
  EXPECT_EQ(newest->line_integral[0].at(0, 0), 9.0f);
  EXPECT_EQ(newest->line_integral[1].at(7, 7), 2.5f);
  EXPECT_EQ(newest->raw[1].at(3, 3), 7);
  EXPECT_EQ(newest->T_room_from_ct.translation().z(), 3.0);
  EXPECT_EQ(feed.newest_images(), nullptr) << "nothing new since";
  // A pair of another size than allocate() saw is not shown (and not half-copied).
  drivers::FramePair other = pair_of(6, 6, 1);
  feed.publish_images(12, 200, true, pose, other, li, valid);
  EXPECT_EQ(feed.newest_images(), nullptr);
}

TEST(CycleFeed, RefusesWhatItCannotShow) {
  CycleFeed feed;
  drivers::FramePair none;
  EXPECT_FALSE(feed.allocate(none, {}).ok());
  drivers::FramePair three = pair_of(4, 4, 0);
  three.frames.push_back(three.frames[0]);
  EXPECT_FALSE(feed.allocate(three, {{0, 0, 4, 4}, {0, 0, 4, 4}, {0, 0, 4, 4}}).ok());
  EXPECT_FALSE(feed.allocate(pair_of(4, 4, 0), {{0, 0, 4, 4}}).ok()) << "a window per view";
}

// A writer publishing as fast as it can and a reader taking what is newest: every set the
// reader gets is whole (every pixel written by one publish) and cycles only increase.
TEST(CycleFeed, AReaderNeverSeesATornOrOlderSet) {
  CycleFeed feed(1024, 0);
  const std::vector<tracking::PixelWindow> windows{{0, 0, 32, 32}, {0, 0, 32, 32}};
  drivers::FramePair pair = pair_of(32, 32, 0);
  ASSERT_TRUE(feed.allocate(pair, windows).ok());
  std::vector<tracking::Image<float>> li(2, tracking::Image<float>(32, 32));
  std::vector<tracking::Image<unsigned char>> valid(2, tracking::Image<unsigned char>(32, 32));
  constexpr int kSets = 20000;
  std::atomic<bool> done{false};
  std::thread writer([&] {
    for (int c = 1; c <= kSets; ++c) {
      for (auto& image : li) std::fill(image.pixels().begin(), image.pixels().end(), float(c));
      for (auto& f : pair.frames) std::fill(f.pixels.pixels().begin(), f.pixels.pixels().end(), std::uint16_t(c));
      feed.publish_images(c, c, true, tracking::Pose::Identity(), pair, li, valid);
    }
    done = true;
  });
  std::int64_t last = 0;
  int seen = 0;
  bool torn = false;
  while (!done || seen == 0) {
    const FeedImages* s = feed.newest_images();
    if (s == nullptr) continue;
    ++seen;
    EXPECT_GT(s->cycle, last);
    last = s->cycle;
    for (int v = 0; v < 2; ++v) {
      for (float x : s->line_integral[std::size_t(v)].pixels()) torn = torn || x != float(s->cycle);
      for (std::uint16_t x : s->raw[std::size_t(v)].pixels()) torn = torn || x != std::uint16_t(s->cycle);
    }
  }
  writer.join();
  EXPECT_FALSE(torn) << "a set mixed two publishes";
  EXPECT_GT(seen, 0);
}

}  // namespace
}  // namespace lftrack::loop
