#include "lftrack/loop/tracking_accuracy.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "lftrack/loop/tracking_states.hpp"

namespace lftrack::loop {
namespace {

JournalRecord tracked(double x_mm, double y_mm, double z_mm, double rz_rad) {
  JournalRecord r;
  r.state = static_cast<std::uint8_t>(TrackingState::kTrack);
  r.true_residual_mm = std::sqrt(x_mm * x_mm + y_mm * y_mm + z_mm * z_mm);
  r.true_target_residual[0] = x_mm;
  r.true_target_residual[1] = y_mm;
  r.true_target_residual[2] = z_mm;
  r.true_target_residual[5] = rz_rad;
  return r;
}

// Per axis mean and sample SD, the 3D error's shares beyond 1 and 2 mm, over TRACK cycles only.
TEST(TrackingAccuracy, ReportsEachAxisAndTheSharesBeyondOneAndTwoMillimetres) {
  TrackingAccuracy a;
  a.add(tracked(0.5, 0, 0, 0.01));
  a.add(tracked(-0.5, 0, 0, -0.01));
  a.add(tracked(1.5, 0, 0, 0.01));    // 1.5 mm: beyond 1 mm
  JournalRecord treating = tracked(0, 2.5, 0, -0.01);  // 2.5 mm: beyond both
  treating.beam_permit = 1;
  a.add(treating);
  JournalRecord held = tracked(9, 9, 9, 0.5);
  held.state = static_cast<std::uint8_t>(TrackingState::kHold);  // not a TRACK cycle
  a.add(held);
  JournalRecord no_truth = tracked(9, 9, 9, 0.5);
  no_truth.true_residual_mm = -1;  // not a simulation
  a.add(no_truth);
  const auto t = a.target_residual();
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->cycles, 4);
  EXPECT_NEAR(t->translation_mean_mm[0], 0.375, 1e-12);
  EXPECT_NEAR(t->translation_mean_mm[1], 0.625, 1e-12);
  EXPECT_NEAR(t->translation_mean_mm[2], 0.0, 1e-12);
  // Sample SD of {0.5, -0.5, 1.5, 0}: mean 0.375, squares 0.015625+0.765625+1.265625+0.140625.
  EXPECT_NEAR(t->translation_sd_mm[0], std::sqrt(2.1875 / 3), 1e-12);
  EXPECT_NEAR(t->rotation_mean_deg[2], 0.0, 1e-12);
  EXPECT_NEAR(t->rotation_sd_deg[2], 0.01 * 180 / std::numbers::pi * std::sqrt(4.0 / 3), 1e-9);
  EXPECT_DOUBLE_EQ(t->share_over_1mm, 0.5);
  EXPECT_DOUBLE_EQ(t->share_over_2mm, 0.25);
  EXPECT_EQ(t->beam_on_cycles, 1);
  EXPECT_DOUBLE_EQ(t->beam_on_share_over_2mm, 1.0);
  EXPECT_NEAR(t->error_3d_max_mm, 2.5, 1e-12);
  EXPECT_FALSE(a.latency().has_value()) << "no command was acknowledged";
}

// Latency runs from the older frame's exposure to the acknowledgement, for commands sent only.
TEST(TrackingAccuracy, LatencyRunsFromTheOlderExposureToTheAcknowledgement) {
  TrackingAccuracy a;
  for (int i = 0; i < 100; ++i) {
    JournalRecord r;
    r.frame_time_ns[0] = 1'000'000'000;
    r.frame_time_ns[1] = 1'002'000'000;  // B exposed 2 ms after A
    r.command_sent = 1;
    r.command_acked_ns = 1'000'000'000 + std::int64_t(i + 1) * 1'000'000;  // 1..100 ms after A
    a.add(r);
  }
  JournalRecord unsent;
  unsent.frame_time_ns[0] = unsent.frame_time_ns[1] = 1;
  unsent.command_acked_ns = 5'000'000'000;  // no command sent: not counted
  a.add(unsent);
  const auto l = a.latency();
  ASSERT_TRUE(l.has_value());
  EXPECT_EQ(l->commands, 100);
  EXPECT_NEAR(l->p50_ms, 50, 0.02);
  EXPECT_NEAR(l->p95_ms, 95, 0.02);
  EXPECT_NEAR(l->p99_ms, 99, 0.02);
  EXPECT_NEAR(l->max_ms, 100, 1e-9);
  EXPECT_FALSE(a.target_residual().has_value()) << "no TRACK cycle with a truth";
}

// A journal before format 4 has no per-axis residual: nothing is reported from its zeros, and a
// non-finite residual (damage the checksum missed) is left out rather than poisoning the means.
TEST(TrackingAccuracy, OldJournalsAndNonFiniteResidualsReportNothingFalse) {
  TrackingAccuracy old(/*records_have_target_residual=*/false);
  old.add(tracked(0, 0, 0, 0));
  EXPECT_FALSE(old.target_residual().has_value());
  TrackingAccuracy a;
  a.add(tracked(std::nan(""), 0, 0, 0));
  a.add(tracked(0.2, 0, 0, 0));
  const auto t = a.target_residual();
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->cycles, 1);
  EXPECT_DOUBLE_EQ(t->translation_mean_mm[0], 0.2);
}

}  // namespace
}  // namespace lftrack::loop
