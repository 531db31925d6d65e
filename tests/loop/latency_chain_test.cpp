// The latency chain's links from a journal record (latency_chain.hpp): they add up to the
// exposure-to-acknowledgement latency, and a record without a whole, ordered chain has none.

#include "lftrack/loop/latency_chain.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace lftrack::loop {
namespace {

constexpr std::int64_t kNsPerMs = 1'000'000;

// A command whose links take 1, 2, 3, 4, 5 and 6 ms from an exposure at 100 ms (detector B's
// frame the older one).
JournalRecord chained() {
  JournalRecord r;
  r.command_sent = 1;
  r.frame_time_ns[0] = 101 * kNsPerMs;
  r.frame_time_ns[1] = 100 * kNsPerMs;
  r.frames_arrived_ns = 101 * kNsPerMs;
  r.preprocessed_ns = 103 * kNsPerMs;
  r.registered_ns = 106 * kNsPerMs;
  r.gated_ns = 110 * kNsPerMs;
  r.command_written_ns = 115 * kNsPerMs;
  r.command_acked_ns = 121 * kNsPerMs;
  return r;
}

TEST(LatencyChain, TheLinksAddUpFromTheOlderExposureToTheAcknowledgement) {
  const auto links = latency_links_ms(chained());
  ASSERT_TRUE(links.has_value());
  double total = 0;
  for (int i = 0; i < kLatencyLinks; ++i) {
    EXPECT_NEAR((*links)[std::size_t(i)], i + 1.0, 1e-9) << to_string(static_cast<LatencyLink>(i));
    total += (*links)[std::size_t(i)];
  }
  EXPECT_NEAR(total, 21.0, 1e-9);
}

TEST(LatencyChain, ARecordWithoutAWholeOrderedChainHasNone) {
  JournalRecord none = chained();
  none.command_sent = 0;
  EXPECT_FALSE(latency_links_ms(none)) << "no command";
  JournalRecord simulated = chained();  // the simulated clock journals no links
  simulated.frames_arrived_ns = simulated.preprocessed_ns = simulated.registered_ns = simulated.gated_ns =
      simulated.command_written_ns = 0;
  EXPECT_FALSE(latency_links_ms(simulated));
  JournalRecord unwritten = chained();  // a link not reached
  unwritten.command_written_ns = 0;
  EXPECT_FALSE(latency_links_ms(unwritten));
  JournalRecord backwards = chained();  // never on one monotonic clock: damage
  backwards.gated_ns = backwards.registered_ns - 1;
  EXPECT_FALSE(latency_links_ms(backwards));
  JournalRecord no_exposure = chained();
  no_exposure.frame_time_ns[0] = no_exposure.frame_time_ns[1] = 0;
  EXPECT_FALSE(latency_links_ms(no_exposure));
  // Each says why.
  NoChain why = NoChain::kNoCommand;
  EXPECT_FALSE(latency_links_ms(simulated, &why));
  EXPECT_EQ(why, NoChain::kNotTimed);
  EXPECT_FALSE(latency_links_ms(backwards, &why));
  EXPECT_EQ(why, NoChain::kOutOfOrder);
  EXPECT_FALSE(latency_links_ms(none, &why));
  EXPECT_EQ(why, NoChain::kNoCommand);
  JournalRecord forever = chained();  // an acknowledgement at the end of time: damage
  forever.command_acked_ns = std::numeric_limits<std::int64_t>::max();
  EXPECT_FALSE(latency_links_ms(forever, &why));
  EXPECT_EQ(why, NoChain::kImplausible);
  for (NoChain n : {NoChain::kNoCommand, NoChain::kNotTimed, NoChain::kOutOfOrder, NoChain::kImplausible})
    EXPECT_STRNE(to_string(n), "?");
}

TEST(LatencyChain, OneDetectorsFrameIsTheExposure) {
  JournalRecord one = chained();  // one detector: the second frame time is not there
  one.frame_time_ns[1] = 0;
  EXPECT_EQ(exposure_ns(one), 101 * kNsPerMs);
  const auto links = latency_links_ms(one);
  ASSERT_TRUE(links.has_value());
  EXPECT_NEAR((*links)[std::size_t(LatencyLink::kArrive)], 0.0, 1e-9);
  EXPECT_EQ(exposure_ns(chained()), 100 * kNsPerMs) << "two: the older";
}

TEST(LatencyChain, TheReportGivesEachLinksQuantilesAndTheTotal) {
  LatencyChain chain;
  EXPECT_FALSE(chain.report()) << "no command yet";
  for (int i = 0; i < 100; ++i) {
    JournalRecord r = chained();
    r.command_acked_ns += i * kNsPerMs / 10;  // the acknowledgement 6.0 to 15.9 ms
    chain.add(r);
  }
  JournalRecord without = chained();
  without.command_sent = 0;
  chain.add(without);
  const auto report = chain.report();
  ASSERT_TRUE(report.has_value());
  EXPECT_EQ(report->commands, 100);
  EXPECT_NEAR(report->links[std::size_t(LatencyLink::kRegister)].p99_ms, 3.0, 0.011);
  const LinkLatency& ack = report->links[std::size_t(LatencyLink::kAcknowledge)];
  EXPECT_NEAR(ack.p50_ms, 10.9, 0.011);  // the 50th of 100: 6.0 + 4.9 ms
  EXPECT_NEAR(ack.max_ms, 15.9, 1e-9);
  EXPECT_NEAR(report->total.max_ms, 30.9, 1e-9);
  EXPECT_NEAR(report->total.p50_ms, 25.9, 0.011);
}

TEST(LatencyChain, EveryLinkHasAName) {
  for (int i = 0; i < kLatencyLinks; ++i) {
    EXPECT_STRNE(to_string(static_cast<LatencyLink>(i)), "?");
    EXPECT_STRNE(key_of(static_cast<LatencyLink>(i)), "?");
  }
}

}  // namespace
}  // namespace lftrack::loop
