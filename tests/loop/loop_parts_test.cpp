// The loop's small parts: motion prediction, running statistics, operator inputs, real-time
// set-up, and the scene keys that configure the loop.

#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cmath>
#include <cstring>

#include "lftrack/host/histogram.hpp"
#include "lftrack/host/motion_predictor.hpp"
#include "lftrack/host/operator_input.hpp"
#include "lftrack/host/realtime_setup.hpp"
#include "lftrack/host/scene.hpp"
#include "lftrack/sim/simulated_room.hpp"
#include "test_data.hpp"

namespace lftrack::host {
namespace {

using tracking::Vector6d;

Vector6d along(double x) {
  Vector6d v = Vector6d::Zero();
  v(2) = x;
  v(3) = 0.01 * x;
  return v;
}

TEST(MotionPredictor, ExtrapolatesLinesAndParabolasExactly) {
  MotionPredictor line(4, 1, 0.2), parabola(6, 2, 0.2);
  for (int k = 0; k < 8; ++k) {
    const double t = 0.1 * k;
    line.add(t, along(1.0 + 2.0 * t));
    parabola.add(t, along(1.0 + 2.0 * t - 3.0 * t * t));
  }
  const double t = 0.7 + 0.2;
  EXPECT_NEAR(line.predict()(2), 1.0 + 2.0 * t, 1e-9);
  EXPECT_NEAR(line.predict()(3), 0.01 * (1.0 + 2.0 * t), 1e-11);
  EXPECT_NEAR(parabola.predict()(2), 1.0 + 2.0 * t - 3.0 * t * t, 1e-9);
  EXPECT_EQ(parabola.size(), 6) << "keeps its window";
}

TEST(MotionPredictor, FewEstimatesResetAndNoPrediction) {
  MotionPredictor p(6, 2, 0.2);
  EXPECT_TRUE(p.predict().isZero());
  p.add(0.0, along(1.0));
  EXPECT_NEAR(p.predict()(2), 1.0, 1e-12) << "one estimate: itself";
  p.add(0.1, along(2.0));
  EXPECT_NEAR(p.predict()(2), 4.0, 1e-9) << "two: a line";
  p.reset();
  p.add(5.0, along(-1.0));
  EXPECT_NEAR(p.predict()(2), -1.0, 1e-12) << "nothing extrapolates across a reset";
  MotionPredictor none(1, 2, 0.2);
  none.add(0.0, along(0.0));
  none.add(0.1, along(1.0));
  EXPECT_NEAR(none.predict()(2), 1.0, 1e-12);
  MotionPredictor same_time(4, 2, 0.2);
  same_time.add(1.0, along(1.0));
  same_time.add(1.0, along(3.0));
  EXPECT_TRUE(same_time.predict().allFinite()) << "a singular fit falls back, never NaN";
}

TEST(Histogram, QuantilesWithinOneBinMeanAndMax) {
  Histogram h(0.01, 10);
  EXPECT_EQ(h.quantile(0.5), 0.0);
  for (int i = 1; i <= 1000; ++i) h.add(0.001 * i);  // 0.001 .. 1.0
  EXPECT_NEAR(h.quantile(0.5), 0.5, 0.011);
  EXPECT_NEAR(h.quantile(0.95), 0.95, 0.011);
  EXPECT_NEAR(h.mean(), 0.5005, 1e-9);
  EXPECT_DOUBLE_EQ(h.max(), 1.0);
  h.add(50.0);  // beyond the range: last bin, exact max
  EXPECT_DOUBLE_EQ(h.max(), 50.0);
  EXPECT_LE(h.quantile(1.0), 50.0);
  h.add(std::nan(""));
  EXPECT_EQ(h.count(), 1002u);
}

TEST(RealtimeSetup, IgnoreAlwaysStartsAndEnforceSaysWhy) {
  RealtimeSpec ignore;
  ignore.priority = 1;
  auto report = apply_realtime_setup(ignore);
  ASSERT_TRUE(report.ok()) << "ignore never refuses";
  EXPECT_FALSE(report->summary().empty());
  RealtimeSpec enforce;
  enforce.enforce = true;  // no CPUs named: refused on any machine, with the reason
  auto refused = apply_realtime_setup(enforce);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("enforce"), std::string::npos) << refused.status().message();
  // Leave the test process as it was.
  sched_param normal{};
  pthread_setschedparam(pthread_self(), SCHED_OTHER, &normal);
}

TEST(SimulatedRoom, CouchThatCancelsTheOffsetLeavesNoResidual) {
  sim::SimulatedRoomSpec spec;
  spec.origin_room_mm = {0, 0, 0};
  spec.setup_error << 2, -1, 3, 0.01, 0.02, -0.01;
  spec.couch.latency_s = 0.1;
  spec.couch.max_speed_mm_s = 1000;
  spec.couch.max_speed_deg_s = 1000;
  sim::SimulatedRoom room(spec);
  room.advance_to_ns(1'000'000'000);  // t = 0
  EXPECT_GT(room.residual_mm(), 3.0);
  const tracking::Pose offset = room.patient_T_room_from_ct();
  const Vector6d cancel =
      tracking::delta_between(offset, spec.nominal_T_room_from_ct, spec.origin_room_mm).as_vector();
  ASSERT_EQ(room.couch_actuator().command(cancel, drivers::Deadline(std::chrono::nanoseconds(1'100'000'000))),
            drivers::DeviceStatus::kOk);
  room.advance_to_ns(1'150'000'000);
  EXPECT_GT(room.residual_mm(), 3.0)
      << "the command was sent at its deadline (t = 0.1 s) and waits out the latency";
  room.advance_to_ns(1'300'000'000);
  EXPECT_LT(room.residual_mm(), 1e-9);
}

TEST(SceneLoopKeys, ParseAndRejectWithLocation) {
  const std::string base = *builtin_scene_text(kBuiltinPhantom);
  auto scene = parse_scene(base, "b.yaml", ".");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->loop.period_ms, 100);
  EXPECT_EQ(scene->actuator.type, "virtual");
  EXPECT_NEAR(scene->motion.motion.breathing_amplitude(2), 4.5, 1e-12);
  EXPECT_NEAR(scene->motion.setup_error(3), tracking::deg_to_rad(1.0), 1e-12);
  EXPECT_EQ(scene->sim.renderer, "lightfield");
  EXPECT_FALSE(scene->loop.realtime.enforce);
  const auto fails = [&](const std::string& extra, const std::string& expect) {
    auto s = parse_scene(base + extra, "b.yaml", ".");
    ASSERT_FALSE(s.ok()) << extra;
    EXPECT_NE(s.status().message().find(expect), std::string::npos) << s.status().message();
  };
  fails("shifts: []\n", "unknown key 'shifts'");
  std::string budget = base;
  budget.replace(budget.find("registration_budget_ms: 50"), 26, "registration_budget_ms: 90");
  auto s = parse_scene(budget, "b.yaml", ".");
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("must fit in period_ms"), std::string::npos) << s.status().message();
  std::string mode = base;
  mode.replace(mode.find("mode: ignore"), 12, "mode: maybe");
  s = parse_scene(mode, "b.yaml", ".");
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("b.yaml:"), std::string::npos);
  std::string actuator = base;
  actuator.replace(actuator.find("type: virtual"), 13, "type: hydraulic");
  EXPECT_FALSE(parse_scene(actuator, "b.yaml", ".").ok());
}

}  // namespace
}  // namespace lftrack::host
