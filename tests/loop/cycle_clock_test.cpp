#include "lftrack/loop/cycle_clock.hpp"

#include <gtest/gtest.h>

#include "lftrack/loop/loop_parts.hpp"

namespace lftrack::loop {
namespace {

constexpr std::int64_t kClockMs = 1'000'000;
constexpr std::int64_t kLoopStart = 1000 * kClockMs, kPeriod = 100 * kClockMs;

// Cycle 3 stalls for 250 ms beyond its period; no other cycle does.
class StallAtThree final : public CycleObserver {
 public:
  void on_cycle(const JournalRecord&) override {}
  std::int64_t simulated_stall_ns(std::int64_t cycle) override { return cycle == 3 ? 250 * kClockMs : 0; }
};

TEST(CycleClock, TheSimulatedClockSeesTheCyclesStartAsNowWhateverTheHostTook) {
  const auto clock = simulated_cycle_clock(nullptr);
  EXPECT_EQ(clock->now_ns(1400 * kClockMs), 1400 * kClockMs);
  // The set-up move after a long cold registration is due at the period's end all the same.
  EXPECT_EQ(clock->command_due_ns(1400 * kClockMs, kPeriod, /*aligning=*/true), 1500 * kClockMs);
  EXPECT_EQ(clock->command_due_ns(1400 * kClockMs, kPeriod, /*aligning=*/false), 1500 * kClockMs);
  EXPECT_EQ(clock->acknowledged_ns(1500 * kClockMs), 1500 * kClockMs);
  EXPECT_EQ(clock->stage_budget_ms(3.5), kUnlimitedStageMs);
  EXPECT_EQ(clock->stage_budget_ms(-2.0), kUnlimitedStageMs);  // a period already spent
  EXPECT_EQ(clock->work_started_ns(10, 20), 20);               // the simulator's rendering is not the loop's
  EXPECT_FALSE(clock->measures_latency());
  EXPECT_TRUE(clock->back_to_back());
}

TEST(CycleClock, TheSimulatedClockRunsTheNextPeriodHoweverLateTheWorkEnded) {
  const auto clock = simulated_cycle_clock(nullptr);
  const NextCycle n = clock->next(kLoopStart, kPeriod, 4, 1400 * kClockMs, /*wall_end_ns=*/9000 * kClockMs);
  EXPECT_EQ(n.index, 5);
  EXPECT_EQ(n.start_ns, 1500 * kClockMs);
  EXPECT_FALSE(n.overrun);
  EXPECT_EQ(n.skipped, 0);
  // It never sleeps: waiting for a start an hour ahead returns (a clock that slept would run into
  // the test's time-out instead).
  clock->wait_until(monotonic_now_ns() + 3'600'000 * kClockMs);
}

TEST(CycleClock, AnInjectedStallOverrunsTheSimulatedClockAsTheHostsWould) {
  StallAtThree observer;
  const auto clock = simulated_cycle_clock(&observer);
  // Cycle 3 (1300 ms) lasts its period and 250 ms: it ends at 1650 ms, so periods 4, 5 and 6 are
  // gone and cycle 7 starts at 1700 ms.
  const NextCycle stalled = clock->next(kLoopStart, kPeriod, 3, 1300 * kClockMs, 0);
  EXPECT_TRUE(stalled.overrun);
  EXPECT_EQ(stalled.skipped, 3);
  EXPECT_EQ(stalled.index, 7);
  EXPECT_EQ(stalled.start_ns, 1700 * kClockMs);
  const NextCycle calm = clock->next(kLoopStart, kPeriod, 7, 1700 * kClockMs, 0);
  EXPECT_FALSE(calm.overrun);
  EXPECT_EQ(calm.index, 8);
}

TEST(CycleClock, TheHostsClockIsTheMonotonicClockAndBoxesStagesByTheirBudget) {
  const auto clock = host_cycle_clock();
  const std::int64_t before = monotonic_now_ns();
  const std::int64_t now = clock->now_ns(/*cycle_start_ns=*/0);
  EXPECT_GE(now, before);
  EXPECT_LE(now, monotonic_now_ns());
  EXPECT_EQ(clock->command_due_ns(1400 * kClockMs, kPeriod, /*aligning=*/false), 1500 * kClockMs);
  // The set-up move gets a period from now, not from a start long past.
  EXPECT_GE(clock->command_due_ns(0, kPeriod, /*aligning=*/true), before + kPeriod);
  EXPECT_GE(clock->acknowledged_ns(0), before);
  EXPECT_EQ(clock->stage_budget_ms(3.5), 3.5);
  EXPECT_EQ(clock->stage_budget_ms(-2.0), -2.0);
  EXPECT_EQ(clock->work_started_ns(10, 20), 10);
  EXPECT_TRUE(clock->measures_latency());
  EXPECT_FALSE(clock->back_to_back());
}

TEST(CycleClock, TheHostsClockSkipsThePeriodsAnOverrunRanIntoAndSleepsUntilTheNextStart) {
  const auto clock = host_cycle_clock();
  const NextCycle n = clock->next(kLoopStart, kPeriod, 4, 1400 * kClockMs, /*wall_end_ns=*/1730 * kClockMs);
  EXPECT_TRUE(n.overrun);
  EXPECT_EQ(n.skipped, 3);
  EXPECT_EQ(n.start_ns, 1800 * kClockMs);
  EXPECT_FALSE(clock->next(kLoopStart, kPeriod, 4, 1400 * kClockMs, 1460 * kClockMs).overrun);
  const std::int64_t t0 = monotonic_now_ns();
  clock->wait_until(t0 + 5 * kClockMs);
  EXPECT_GE(monotonic_now_ns(), t0 + 5 * kClockMs);
}

}  // namespace
}  // namespace lftrack::loop
