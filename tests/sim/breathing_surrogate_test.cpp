// The simulated breathing surrogate (issue 58): its curve, rate, lead, drift and noise.
#include "lftrack/sim/breathing_surrogate.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace lftrack::sim {

using sim_spec::BreathingSurrogateSpec;
namespace {

TEST(BreathingSurrogate, RestsAtExhaleAndPeaksHalfAPeriodLater) {
  BreathingSurrogateSpec spec;
  spec.lead_s = 0;
  spec.noise_sd = 0;
  BreathingSurrogate s(spec);
  EXPECT_NEAR(s.exact(0), 0, 1e-12);
  EXPECT_NEAR(s.exact(spec.period_s / 2), spec.amplitude, 1e-12);
  EXPECT_NEAR(s.sample(1.3), s.exact(1.3), 1e-12) << "no noise asked for";
}

TEST(BreathingSurrogate, TheRateIsTheCurvesDerivative) {
  BreathingSurrogateSpec spec;
  spec.drift_per_s = 0.01;
  BreathingSurrogate s(spec);
  for (double t = 0; t < 8; t += 0.37) {
    const double h = 1e-5;
    EXPECT_NEAR(s.exact_rate_per_s(t), (s.exact(t + h) - s.exact(t - h)) / (2 * h), 1e-6) << t;
  }
}

TEST(BreathingSurrogate, TheChestLeadsByLeadS) {
  BreathingSurrogateSpec leading;
  leading.lead_s = 0.3;
  BreathingSurrogateSpec in_step = leading;
  in_step.lead_s = 0;
  const BreathingSurrogate a(leading), b(in_step);
  for (double t = 0; t < 8; t += 0.5) EXPECT_NEAR(a.exact(t), b.exact(t + 0.3), 1e-12);
}

TEST(BreathingSurrogate, TheNoiseHasItsDeviationAndItsSeed) {
  BreathingSurrogateSpec spec;
  spec.noise_sd = 0.2;
  BreathingSurrogate a(spec), b(spec);
  double sum2 = 0;
  const int n = 20000;
  for (int i = 0; i < n; ++i) {
    const double t = i / 60.0;
    const double reading = a.sample(t);
    ASSERT_EQ(reading, b.sample(t)) << "the same seed, the same stream";
    const double e = reading - a.exact(t);
    sum2 += e * e;
  }
  EXPECT_NEAR(std::sqrt(sum2 / n), 0.2, 0.01);
}

}  // namespace
}  // namespace lftrack::sim
