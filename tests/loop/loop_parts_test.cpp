// The loop's small parts: motion prediction, running statistics, real-time set-up.

#include <gtest/gtest.h>
#include <sched.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <tuple>
#include <vector>

#include "lftrack/loop/histogram.hpp"
#include "lftrack/loop/motion_predictor.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/realtime_setup.hpp"
#include "test_data.hpp"

namespace lftrack::loop {
namespace {

using tracking::Vector6d;

Vector6d along(double x) {
  Vector6d v = Vector6d::Zero();
  v(2) = x;
  v(3) = 0.01 * x;
  return v;
}

constexpr std::int64_t kNsPerMs = 1'000'000;

TEST(MotionPredictor, ExtrapolatesTranslationsOnLinesAndParabolasExactlyAndRotationsNot) {
  MotionPredictor line(4, 1, 0.2), parabola(8, 2, 0.2);
  for (int k = 0; k < 8; ++k) {
    const double t = 0.1 * k;
    line.add(100 * kNsPerMs * k, along(1.0 + 2.0 * t));
    parabola.add(100 * kNsPerMs * k, along(1.0 + 2.0 * t - 3.0 * t * t));
  }
  const double t = 0.7 + 0.2;
  EXPECT_NEAR(line.predict()(2), 1.0 + 2.0 * t, 1e-9);
  // Rotations are not extrapolated: the newest estimate's (at 0.7 s).
  EXPECT_NEAR(line.predict()(3), 0.01 * (1.0 + 2.0 * 0.7), 1e-11);
  EXPECT_NEAR(parabola.predict()(3), 0.01 * (1.0 + 2.0 * 0.7 - 3.0 * 0.49), 1e-11);
  EXPECT_NEAR(parabola.predict()(2), 1.0 + 2.0 * t - 3.0 * t * t, 1e-9);
  EXPECT_EQ(parabola.size(), 8) << "keeps its window";
  // A scene that asks for it (loop.predict_rotations) has its rotations extrapolated too.
  MotionPredictor rotating(4, 1, 0.2, /*predict_rotations=*/true);
  for (int k = 0; k < 8; ++k) rotating.add(100 * kNsPerMs * k, along(1.0 + 2.0 * 0.1 * k));
  EXPECT_NEAR(rotating.predict()(3), 0.01 * (1.0 + 2.0 * t), 1e-11);
}

// The prediction is linear in the estimates; its weights' norm is how much it multiplies
// independent noise. Measured from outside: the prediction of a unit estimate at one place and
// zeros elsewhere is that place's weight.
double noise_gain(int window, int order, double lookahead_s, const std::vector<std::int64_t>& times_ns) {
  double sum_of_squares = 0;
  for (std::size_t unit = 0; unit < times_ns.size(); ++unit) {
    MotionPredictor p(window, order, lookahead_s);
    for (std::size_t i = 0; i < times_ns.size(); ++i) p.add(times_ns[i], along(i == unit ? 1.0 : 0.0));
    sum_of_squares += p.predict()(2) * p.predict()(2);
  }
  return std::sqrt(sum_of_squares);
}

// After an alignment or a resume the history starts empty; a parabola through its first 4
// estimates, 0.2 s ahead at 10 Hz, multiplied their noise by 5.7, and a registration's 0.15 degree
// of rotational noise became a step the gate held. While the history fills, the order drops until
// the noise gain is at most 2.5; a full window as the scenes set it predicts as configured.
TEST(MotionPredictor, NeverMultipliesTheEstimatesNoiseByMoreThanTwoAndAHalf) {
  struct Rate {
    int window;
    double period_s, lookahead_s;
  };
  for (const Rate rate : {Rate{8, 0.1, 0.2}, Rate{24, 1.0 / 30, 0.1 + 1.0 / 30}, Rate{6, 0.1, 0.2}}) {
    std::vector<std::int64_t> times_ns;
    for (int k = 0; k < rate.window; ++k) {
      // Frames a little late now and then, as on a loaded host.
      times_ns.push_back(std::llround(1e9 * rate.period_s * k) + (k % 3 == 2 ? 7 * kNsPerMs : 0));
      const double gain = noise_gain(rate.window, 2, rate.lookahead_s, times_ns);
      EXPECT_LE(gain, MotionPredictor::kMaxNoiseGain + 1e-9) << rate.window << " cycles, after " << k + 1;
      EXPECT_GE(gain, k == 0 ? 1.0 - 1e-12 : 0.3) << "one estimate is predicted as itself";
    }
  }
  // The scenes' full windows keep their parabola: it reproduces a parabola exactly, which the
  // line it would otherwise drop to does not.
  for (const auto& [window, period_s, lookahead_s] : {std::tuple{8, 0.1, 0.2}, std::tuple{24, 1.0 / 30, 0.1 + 1.0 / 30}}) {
    MotionPredictor p(window, 2, lookahead_s);
    for (int k = 0; k < window; ++k) {
      const double t = period_s * k;
      p.add(std::llround(1e9 * t), along(t * t));
    }
    const double t = period_s * (window - 1) + lookahead_s;
    EXPECT_NEAR(p.predict()(2), t * t, 1e-9) << window << " cycles";
  }
}

// What a scene's full window predicts with, as the loop session reports it (a warning for a window
// too short for its order): the order predict() uses, and gains equal to those measured from
// outside on evenly spaced estimates.
TEST(MotionPredictor, TellsWhatAFullWindowPredictsWith) {
  struct Case {
    int window, order;
    double period_s, lookahead_s;
    int order_used;
  };
  for (const Case c : {Case{8, 2, 0.1, 0.2, 2}, Case{24, 2, 1.0 / 30, 0.1 + 1.0 / 30, 2}, Case{6, 2, 0.1, 0.2, 1},
                       Case{2, 1, 0.1, 0.2, 0}, Case{3, 2, 0.1, 0.2, 1}, Case{8, 1, 0.1, 0.2, 1}}) {
    SCOPED_TRACE(std::to_string(c.window) + " cycles, order " + std::to_string(c.order));
    const MotionPredictor::FullWindow w = MotionPredictor::full_window(c.window, c.order, c.period_s, c.lookahead_s);
    EXPECT_EQ(w.order_used, c.order_used);
    std::vector<std::int64_t> times_ns;
    for (int k = 0; k < c.window; ++k) times_ns.push_back(std::llround(1e9 * c.period_s * k));
    EXPECT_NEAR(w.gain_used, noise_gain(c.window, c.order, c.lookahead_s, times_ns), 1e-7);  // ns rounding
    if (c.order_used == c.order) {
      EXPECT_DOUBLE_EQ(w.gain_configured, w.gain_used);
    } else {
      EXPECT_GT(w.gain_configured, MotionPredictor::kMaxNoiseGain);
    }
    EXPECT_FALSE(std::isnan(w.gain_configured));
  }
  // The window of 6 at 10 Hz, docs/scenes.md's example: a parabola would multiply noise by 3.06.
  EXPECT_NEAR(MotionPredictor::full_window(6, 2, 0.1, 0.2).gain_configured, 3.06, 0.01);
  // No prediction, and absurd periods: the newest estimate, gain 1.
  for (const double period_s : {0.0, -1.0, std::nan("")})
    EXPECT_EQ(MotionPredictor::full_window(8, 2, period_s, 0.2).order_used, 0) << period_s;
  EXPECT_EQ(MotionPredictor::full_window(1, 2, 0.1, 0.2).order_used, 0);
  // Too few estimates for a parabola: it is never fitted, so it has no gain of its own.
  EXPECT_EQ(MotionPredictor::full_window(3, 2, 0.1, 0.2).gain_configured, INFINITY);
}

// Only differences of time count, so the same estimates give the same prediction bit for bit at
// any clock origin: a loop on the simulated clock starts at the host's uptime, and two runs of
// one seed must agree (with seconds as doubles they drifted apart from the third cycle on).
TEST(MotionPredictor, ThePredictionDoesNotDependOnTheClocksOrigin) {
  const std::int64_t origins[] = {0, 11'532'174'319'670, -5'000'000'000'000,
                                  std::numeric_limits<std::int64_t>::max() - 2000 * kNsPerMs};
  std::vector<Vector6d> predictions;
  for (const std::int64_t origin : origins) {
    MotionPredictor p(6, 2, 0.137);
    for (int k = 0; k < 9; ++k) {
      const double t = 0.0333 * k;
      p.add(origin + 33 * kNsPerMs * k + 300'000 * (k % 3), along(0.3 + std::sin(7.1 * t) + 0.001 * k * k));
    }
    predictions.push_back(p.predict());
  }
  for (std::size_t i = 1; i < predictions.size(); ++i)
    EXPECT_EQ(predictions[i], predictions[0]) << "origin " << origins[i];
  // Times further apart than int64 holds (a device's garbage timestamps) still predict finitely.
  MotionPredictor absurd(4, 2, 0.2);
  absurd.add(std::numeric_limits<std::int64_t>::min(), along(1.0));
  absurd.add(0, along(2.0));
  absurd.add(std::numeric_limits<std::int64_t>::max(), along(3.0));
  EXPECT_TRUE(absurd.predict().allFinite());
}

TEST(MotionPredictor, FewEstimatesResetAndNoPrediction) {
  MotionPredictor p(6, 2, 0.2);
  EXPECT_TRUE(p.predict().isZero());
  p.add(0, along(1.0));
  EXPECT_NEAR(p.predict()(2), 1.0, 1e-12) << "one estimate: itself";
  p.add(100 * kNsPerMs, along(2.0));
  EXPECT_NEAR(p.predict()(2), 2.0, 1e-12) << "two, 0.2 s ahead: a line would multiply their noise by 3.6";
  p.add(200 * kNsPerMs, along(3.0));
  EXPECT_NEAR(p.predict()(2), 5.0, 1e-9) << "three: a line (noise gain 2.2)";
  p.reset();
  p.add(5000 * kNsPerMs, along(-1.0));
  EXPECT_NEAR(p.predict()(2), -1.0, 1e-12) << "nothing extrapolates across a reset";
  MotionPredictor none(1, 2, 0.2);
  none.add(0, along(0.0));
  none.add(100 * kNsPerMs, along(1.0));
  EXPECT_NEAR(none.predict()(2), 1.0, 1e-12);
  MotionPredictor same_time(4, 2, 0.2);
  same_time.add(1000 * kNsPerMs, along(1.0));
  same_time.add(1000 * kNsPerMs, along(3.0));
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

// The memory this process has locked (VmLck in /proc/self/status), in kB.
long locked_kb() {
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);)
    if (line.rfind("VmLck:", 0) == 0) return std::strtol(line.c_str() + 6, nullptr, 10);
  return -1;
}

// `lftrack run --check` asks whether the set-up could be applied, and applies none of it (issue
// 50: the check ran at SCHED_FIFO 80 with its memory locked); with or without the privileges.
TEST(RealtimeSetup, ACheckAppliesNothing) {
  cpu_set_t allowed;
  CPU_ZERO(&allowed);
  ASSERT_EQ(sched_getaffinity(0, sizeof allowed, &allowed), 0);
  int cpu = 0;
  while (!CPU_ISSET(cpu, &allowed)) ++cpu;
  ASSERT_EQ(sched_getscheduler(0), SCHED_OTHER) << "the test starts under normal scheduling";
  const long locked_before = locked_kb();
  RealtimeSpec spec;
  spec.enforce = true;
  spec.priority = 80;
  spec.cpus = {cpu};
  auto checked = check_realtime_setup(spec);
  EXPECT_EQ(sched_getscheduler(0), SCHED_OTHER) << "no SCHED_FIFO taken";
  EXPECT_EQ(locked_kb(), locked_before) << "no memory locked";
  if (checked.ok()) {
    EXPECT_EQ(checked->summary().rfind("nothing applied (a check)", 0), 0u) << checked->summary();
  } else {
    EXPECT_NE(checked.status().message().find("nothing applied"), std::string::npos) << checked.status().message();
  }
  spec.cpus = {CPU_SETSIZE + 1};  // no such CPU: refused with the reason, whatever the privileges
  auto outside = check_realtime_setup(spec);
  ASSERT_FALSE(outside.ok());
  EXPECT_NE(outside.status().message().find("not among this process's CPUs"), std::string::npos)
      << outside.status().message();
  EXPECT_EQ(realtime_not_applied("loop.realtime.mode: ignore").summary(),
            "not applied (loop.realtime.mode: ignore): normal scheduling, memory not locked");
}

}  // namespace
}  // namespace lftrack::loop
