// The frame archive: what the cycle appends is what the replay format reads back, byte for byte;
// a full set of slots drops (and counts) a pair instead of blocking; bad set-ups are refused.

#include "lftrack/loop/frame_archive.hpp"

#include <gtest/gtest.h>

#include <chrono>

#include "lftrack/drivers/frame_files.hpp"
#include "lftrack/drivers/frame_sequence.hpp"
#include "test_data.hpp"

namespace lftrack::loop {
namespace {

drivers::FramePair make_pair(int rows, int cols, int seed) {
  drivers::FramePair pair;
  for (int v = 0; v < 2; ++v) {
    drivers::Frame f;
    f.pixels = tracking::Image<std::uint16_t>(rows, cols);
    for (int i = 0; i < rows * cols; ++i)
      f.pixels.pixels()[std::size_t(i)] = std::uint16_t((seed * 7919 + i * 31 + v) & 0xffff);
    f.sequence = std::uint32_t(seed);
    f.timestamp_ns = 1'000'000'000LL + seed * 100'000'000LL + v * 500;
    pair.frames.push_back(std::move(f));
  }
  return pair;
}

TEST(FrameArchive, ArchivedPairsReadBackExactlyInTheReplayFormat) {
  test::TempDir dir;
  FrameArchiveOptions options;
  options.with_actuator = true;
  auto archive = FrameArchive::open(dir.path() / "seq", {{"AP", 24, 32}, {"LAT", 24, 32}}, options);
  ASSERT_TRUE(archive.ok()) << archive.status().message();
  std::vector<drivers::FramePair> sent;
  for (int k = 0; k < 6; ++k) {
    sent.push_back(make_pair(24, 32, k));
    const tracking::Vector6d travel = tracking::Vector6d::Constant(0.1 * k);
    // 16 slots: six pairs fit even if the writer has not started.
    ASSERT_TRUE((*archive)->append(k, sent.back(), k == 3 ? nullptr : &travel));
  }
  ASSERT_TRUE((*archive)->close().ok());
  EXPECT_EQ((*archive)->pairs_written(), 6u);
  EXPECT_EQ((*archive)->pairs_dropped(), 0u);

  auto sequence = drivers::read_frame_sequence(dir.path() / "seq");
  ASSERT_TRUE(sequence.ok()) << sequence.status().message();
  EXPECT_EQ(sequence->detectors, (std::vector<std::string>{"AP", "LAT"}));
  ASSERT_EQ(sequence->pairs.size(), 6u);
  for (std::size_t k = 0; k < 6; ++k) {
    const drivers::SequencePair& p = sequence->pairs[k];
    EXPECT_EQ(p.index, std::int64_t(k));
    EXPECT_EQ(p.has_actuator, k != 3);
    if (k != 3) {
      EXPECT_NEAR(p.actuator_travel[4], 0.1 * double(k), 1e-12);
    }
    for (std::size_t v = 0; v < 2; ++v) {
      EXPECT_EQ(p.frames[v].sequence, sent[k].frames[v].sequence);
      EXPECT_EQ(p.frames[v].timestamp_ns, sent[k].frames[v].timestamp_ns);
      tracking::Image<std::uint16_t> back(24, 32);
      ASSERT_TRUE(drivers::read_frame_file(p.frames[v].path.c_str(), back.view()).ok());
      EXPECT_EQ(back.pixels(), sent[k].frames[v].pixels.pixels()) << "pair " << k << " view " << v;
    }
  }
}

TEST(FrameArchive, AFullArchiveDropsAndCountsInsteadOfBlocking) {
  test::TempDir dir;
  FrameArchiveOptions options;
  options.slots = 1;
  auto archive = FrameArchive::open(dir.path(), {{"A", 256, 256}, {"B", 256, 256}}, options);
  ASSERT_TRUE(archive.ok());
  const drivers::FramePair pair = make_pair(256, 256, 1);
  int accepted = 0;
  for (int k = 0; k < 40; ++k) accepted += (*archive)->append(k, pair) ? 1 : 0;
  ASSERT_TRUE((*archive)->close().ok());
  EXPECT_EQ((*archive)->pairs_written(), std::uint64_t(accepted));
  EXPECT_EQ((*archive)->pairs_written() + (*archive)->pairs_dropped(), 40u);
  auto sequence = drivers::read_frame_sequence(dir.path());
  ASSERT_TRUE(sequence.ok());
  EXPECT_EQ(sequence->pairs.size(), std::size_t(accepted)) << "the index lists exactly what was written";
  // A pair of another shape is dropped, not written half.
  EXPECT_FALSE((*archive)->append(99, make_pair(8, 8, 2)));
}

// What the simulated clock does before each cycle: wait for a free slot instead of dropping.
// Two slots and a hundred pairs appended as fast as the wait allows: not one is dropped.
TEST(FrameArchive, WaitingForASlotKeepsEveryPair) {
  test::TempDir dir;
  FrameArchiveOptions options;
  options.slots = 2;
  auto archive = FrameArchive::open(dir.path() / "seq", {{"AP", 64, 64}, {"LAT", 64, 64}}, options);
  ASSERT_TRUE(archive.ok()) << archive.status().message();
  const drivers::FramePair pair = make_pair(64, 64, 1);
  for (int k = 0; k < 100; ++k) {
    ASSERT_TRUE((*archive)->wait_for_slot(std::chrono::seconds(30))) << "pair " << k;
    ASSERT_TRUE((*archive)->append(k, pair)) << "pair " << k;
  }
  ASSERT_TRUE((*archive)->close().ok());
  EXPECT_EQ((*archive)->pairs_written(), 100u);
  EXPECT_EQ((*archive)->pairs_dropped(), 0u);
  EXPECT_FALSE((*archive)->wait_for_slot(std::chrono::seconds(1))) << "a closed archive has no slot to wait for";
}

TEST(FrameArchive, BadSetUpsAreRefused) {
  test::TempDir dir;
  EXPECT_FALSE(FrameArchive::open(dir.path(), {}).ok());
  EXPECT_FALSE(FrameArchive::open(dir.path(), {{"A,B", 4, 4}}).ok());
  EXPECT_FALSE(FrameArchive::open("/proc/no-such-place/seq", {{"A", 4, 4}}).ok());
}

}  // namespace
}  // namespace lftrack::loop
