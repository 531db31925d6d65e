// The frames' photon noise: draws against the Poisson distribution itself, small and large means.

#include "lftrack/sim/poisson_sampler.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace lftrack::sim {
namespace {

TEST(PoissonDraw, MeanAndVarianceMatchAcrossMeans) {
  std::mt19937_64 rng(7);
  for (const double mean : {0.5, 3.0, 9.9, 10.0, 37.5, 899.0, 1e6}) {
    constexpr int kDraws = 100000;
    double sum = 0, sum2 = 0;
    for (int i = 0; i < kDraws; ++i) {
      const double k = double(poisson_draw(mean, rng));
      ASSERT_GE(k, 0.0);
      sum += k;
      sum2 += k * k;
    }
    const double m = sum / kDraws, var = sum2 / kDraws - m * m;
    // Five standard errors: of the mean sqrt(mean / n), of the variance about mean sqrt(2 / n).
    EXPECT_NEAR(m, mean, 5 * std::sqrt(mean / kDraws)) << mean;
    EXPECT_NEAR(var, mean, 5 * mean * std::sqrt(2.0 / kDraws) + 5 * std::sqrt(mean / kDraws)) << mean;
  }
}

TEST(PoissonDraw, FollowsTheProbabilitiesOnBothSidesOfTheMethodSwitch) {
  std::mt19937_64 rng(11);
  for (const double mean : {3.0, 20.0}) {
    constexpr int kDraws = 200000;
    std::vector<int> counts(200, 0);
    for (int i = 0; i < kDraws; ++i) ++counts[std::size_t(std::min<std::int64_t>(poisson_draw(mean, rng), 199))];
    for (int k = 0; k < 60; ++k) {
      const double p = std::exp(-mean + k * std::log(mean) - std::lgamma(k + 1.0));
      if (p * kDraws < 50) continue;  // too few expected draws to judge
      const double expected = p * kDraws;
      EXPECT_NEAR(counts[std::size_t(k)], expected, 5 * std::sqrt(expected)) << "mean " << mean << ", k " << k;
    }
  }
}

TEST(PoissonDraw, RepeatableBySeedAndZeroForNoMean) {
  std::mt19937_64 a(3), b(3);
  for (int i = 0; i < 1000; ++i) EXPECT_EQ(poisson_draw(123.4, a), poisson_draw(123.4, b));
  EXPECT_EQ(poisson_draw(0.0, a), 0);
  EXPECT_EQ(poisson_draw(-1.0, a), 0);
}

}  // namespace
}  // namespace lftrack::sim
