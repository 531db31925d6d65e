#include "lftrack/loop/cycle_schedule.hpp"

#include <gtest/gtest.h>

namespace lftrack::loop {
namespace {

constexpr std::int64_t kMs = 1'000'000;

TEST(CycleSchedule, OnTimeCyclesFollowAbsoluteDeadlines) {
  const NextCycle n = next_cycle(1000 * kMs, 100 * kMs, 4, 1460 * kMs);  // cycle 4 ran 1400..1460
  EXPECT_EQ(n.index, 5);
  EXPECT_EQ(n.start_ns, 1500 * kMs);
  EXPECT_FALSE(n.overrun);
  EXPECT_EQ(n.skipped, 0);
}

TEST(CycleSchedule, AnOverrunSkipsTheMissedPeriodsInsteadOfCatchingUp) {
  // Cycle 4 started at 1400 ms and ended at 1730 ms: periods 5, 6 and 7 are gone.
  const NextCycle n = next_cycle(1000 * kMs, 100 * kMs, 4, 1730 * kMs);
  EXPECT_TRUE(n.overrun);
  EXPECT_EQ(n.skipped, 3);
  EXPECT_EQ(n.index, 8);
  EXPECT_EQ(n.start_ns, 1800 * kMs);
  // Ending exactly on the next start is on time.
  EXPECT_FALSE(next_cycle(1000 * kMs, 100 * kMs, 4, 1500 * kMs).overrun);
  // One nanosecond late skips one period.
  EXPECT_EQ(next_cycle(1000 * kMs, 100 * kMs, 4, 1500 * kMs + 1).skipped, 1);
}

TEST(CycleSchedule, SleepsUntilAnAbsoluteTime) {
  const std::int64_t t0 = monotonic_now_ns();
  sleep_until_ns(t0 + 5 * kMs);
  EXPECT_GE(monotonic_now_ns(), t0 + 5 * kMs);
  sleep_until_ns(t0 - 1000 * kMs);  // in the past: returns at once
}

}  // namespace
}  // namespace lftrack::loop
