// The replay source: pairs in order with their recorded offsets, paced or as fast as possible;
// a missing, unreadable or wrong-sized frame is a faulted pair, counted by kind, never a stale
// or half pair; the end of the sequence says so. And the recorded couch read-back.

#include "lftrack/drivers/replay_frame_source.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <fstream>

#include "lftrack/drivers/frame_files.hpp"
#include "lftrack/drivers/recorded_actuator.hpp"
#include "test_data.hpp"

namespace lftrack::drivers {
namespace {

constexpr int kRows = 8, kCols = 12;
constexpr std::int64_t kPeriodNs = 20'000'000;  // the recording's pace

// A recorded sequence of `pairs` pairs of detectors A and B; pixel values encode pair and view;
// B is exposed 300 us after A.
class Replay : public ::testing::Test {
 protected:
  void SetUp() override { write_sequence(5); }
  void write_sequence(int pairs) {
    SequenceIndexWriter writer;
    ASSERT_TRUE(writer.open(dir_.path(), true).ok());
    for (int p = 0; p < pairs; ++p) {
      for (int v = 0; v < 2; ++v) {
        tracking::Image<std::uint16_t> frame(kRows, kCols, std::uint16_t(100 * p + v));
        const std::string name = "frames/" + std::to_string(p) + (v == 0 ? "-A.tif" : "-B.png");
        ASSERT_TRUE(write_frame_file((dir_.path() / name).c_str(), frame.view()).ok());
        ASSERT_TRUE(writer
                        .append(p, v == 0 ? "A" : "B", std::uint32_t(1000 + p),
                                5'000'000'000 + p * kPeriodNs + v * 300'000, name.c_str())
                        .ok());
      }
      const double travel[6] = {double(p), 0, 0, 0, 0, 0};
      ASSERT_TRUE(writer.append_actuator(p, travel).ok());
    }
    ASSERT_TRUE(writer.close().ok());
  }
  std::unique_ptr<ReplayFrameSource> open(bool realtime, std::vector<DetectorShape> shapes = {}) {
    if (shapes.empty()) shapes = {{"A", kRows, kCols}, {"B", kRows, kCols}};
    auto sequence = read_frame_sequence(dir_.path());
    EXPECT_TRUE(sequence.ok()) << sequence.status().message();
    auto source = std::make_unique<ReplayFrameSource>(*sequence, shapes, ReplayOptions{realtime});
    const Status s = source->open(&pair_);
    EXPECT_TRUE(s.ok()) << s.message();
    return source;
  }
  static Deadline far() { return std::chrono::steady_clock::now() + std::chrono::seconds(10); }

  test::TempDir dir_;
  FramePair pair_;
};

TEST_F(Replay, AsFastAsPossibleDeliversEveryPairInOrderThenEnds) {
  auto source = open(false);
  ASSERT_EQ(pair_.frames.size(), 2u);
  for (int p = 0; p < 5; ++p) {
    const std::int64_t exposure = 77'000'000 + p * 100'000'000;  // the loop's (simulated) clock
    source->request_exposure(exposure);
    ASSERT_EQ(source->acquire(&pair_, far()), DeviceStatus::kOk) << p;
    EXPECT_EQ(pair_.frames[0].pixels.at(3, 4), 100 * p);
    EXPECT_EQ(pair_.frames[1].pixels.at(7, 11), 100 * p + 1);
    EXPECT_EQ(pair_.frames[0].sequence, std::uint32_t(1000 + p));
    EXPECT_EQ(pair_.frames[0].timestamp_ns, exposure);
    EXPECT_EQ(pair_.frames[1].timestamp_ns, exposure + 300'000) << "the skew within the pair is kept";
    EXPECT_FALSE(source->exhausted());
  }
  source->request_exposure(600'000'000);
  EXPECT_EQ(source->acquire(&pair_, far()), DeviceStatus::kDisconnected);
  EXPECT_TRUE(source->exhausted());
  EXPECT_EQ(source->counters().pairs_delivered, 5);
}

TEST_F(Replay, RealTimeKeepsTheRecordedPaceAndSkipsPairsALateLoopMissed) {
  auto source = open(true);
  using Clock = std::chrono::steady_clock;
  const auto ns = [](Clock::time_point t) {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
  };
  const std::int64_t start = ns(Clock::now());
  source->request_exposure(start);
  ASSERT_EQ(source->acquire(&pair_, far()), DeviceStatus::kOk);
  EXPECT_EQ(pair_.frames[0].timestamp_ns, start);
  // Asked again: pair 1 is due 20 ms after the start; a deadline before then (10 ms after the
  // start, however long the first pair took to read) times out at once.
  source->request_exposure(start);
  EXPECT_EQ(source->acquire(&pair_, Clock::time_point(std::chrono::nanoseconds(start + kPeriodNs / 2))),
            DeviceStatus::kTimeout);
  EXPECT_EQ(source->counters().late, 1);
  // With time to wait, pair 1 arrives when due.
  ASSERT_EQ(source->acquire(&pair_, far()), DeviceStatus::kOk);
  EXPECT_EQ(pair_.frames[0].pixels.at(0, 0), 100);
  EXPECT_EQ(pair_.frames[0].timestamp_ns, start + kPeriodNs);
  EXPECT_GE(ns(Clock::now()), start + kPeriodNs);
  // A loop that asks 50 ms in gets the last pair due by then (pair 2 is skipped).
  source->request_exposure(start + 2 * kPeriodNs + kPeriodNs / 2 + 10 * 1'000'000);
  ASSERT_EQ(source->acquire(&pair_, far()), DeviceStatus::kOk);
  EXPECT_EQ(pair_.frames[0].pixels.at(0, 0), 300);
  EXPECT_EQ(pair_.frames[1].timestamp_ns, start + 3 * kPeriodNs + 300'000);
}

TEST_F(Replay, BadFramesFaultThePairAndAreCountedByKind) {
  std::filesystem::remove(dir_.path() / "frames/1-B.png");
  std::ofstream(dir_.path() / "frames/2-A.tif", std::ios::trunc) << "garbage";
  const tracking::Image<std::uint16_t> small(4, 4);
  ASSERT_TRUE(write_frame_file((dir_.path() / "frames/3-B.png").c_str(), small.view()).ok());
  auto source = open(false);
  const DeviceStatus expected[5] = {DeviceStatus::kOk, DeviceStatus::kFault, DeviceStatus::kFault,
                                    DeviceStatus::kFault, DeviceStatus::kOk};
  for (int p = 0; p < 5; ++p) {
    source->request_exposure(p);
    EXPECT_EQ(source->acquire(&pair_, far()), expected[p]) << "pair " << p;
  }
  const ReplayCounters& c = source->counters();
  EXPECT_EQ(c.pairs_delivered, 2);
  EXPECT_EQ(c.missing, 1);
  EXPECT_EQ(c.unreadable, 1);
  EXPECT_EQ(c.wrong_size, 1);
  EXPECT_EQ(pair_.frames[0].pixels.at(0, 0), 400) << "the last good pair, whole";
}

TEST_F(Replay, ADetectorTheSequenceLacksIsRefusedAtOpen) {
  auto sequence = read_frame_sequence(dir_.path());
  ASSERT_TRUE(sequence.ok());
  ReplayFrameSource source(*sequence, {{"A", kRows, kCols}, {"LAT", kRows, kCols}}, {});
  const Status s = source.open(&pair_);
  EXPECT_EQ(s.code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(s.message().find("no frames of detector 'LAT' (it has A, B)"), std::string::npos) << s.message();
}

TEST_F(Replay, ADetectorTheSceneLacksIsRefusedAtOpen) {
  auto sequence = read_frame_sequence(dir_.path());
  ASSERT_TRUE(sequence.ok());
  ReplayFrameSource source(*sequence, {{"A", kRows, kCols}}, {});
  const Status s = source.open(&pair_);
  EXPECT_EQ(s.code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(s.message().find("frames of detector 'B', which the scene does not have (it has A)"), std::string::npos)
      << s.message();
}

TEST_F(Replay, TheRecordedCouchReadsBackTheDeliveredPairsTravelAndMovesNothing) {
  auto source = open(false);
  RecordedActuator couch(source.get());
  ASSERT_TRUE(couch.open().ok());
  ActuatorState state;
  EXPECT_EQ(couch.readback(&state, far()), DeviceStatus::kFault) << "no pair delivered yet";
  for (int p = 0; p < 3; ++p) {
    source->request_exposure(p);
    ASSERT_EQ(source->acquire(&pair_, far()), DeviceStatus::kOk);
    ASSERT_EQ(couch.readback(&state, far()), DeviceStatus::kOk);
    EXPECT_DOUBLE_EQ(state.position(0), p);
  }
  tracking::Vector6d step = tracking::Vector6d::Zero();
  step(1) = 0.5;
  EXPECT_EQ(couch.command(step, far()), DeviceStatus::kOk);
  ASSERT_EQ(couch.readback(&state, far()), DeviceStatus::kOk);
  EXPECT_DOUBLE_EQ(state.target(1), 0.5) << "the command is reported";
  EXPECT_DOUBLE_EQ(state.position(1), 0.0) << "and moves nothing";
  step(1) = std::nan("");
  EXPECT_EQ(couch.command(step, far()), DeviceStatus::kFault);
}

}  // namespace
}  // namespace lftrack::drivers
