// Mutual information's integer sub-histograms against a plain reference: the textbook
// partial-volume joint histogram accumulated in double, one pixel after another.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "lftrack/tracking/similarity.hpp"

namespace lftrack::tracking {
namespace {

// The reference: moving values split linearly between their two nearest of `bins` bins over the
// usable pixels' range, fixed values binned over theirs; MI (or NMI) in nats.
double reference_mi(const Image<float>& fixed, const Image<unsigned char>& fixed_valid, const Image<float>& moving,
                    const Image<unsigned char>& moving_valid, int bins, bool normalised) {
  const int rows = fixed.rows(), cols = fixed.cols();
  auto usable_fixed = [&](int r, int c) { return std::isfinite(fixed.at(r, c)) && fixed_valid.at(r, c) != 0; };
  auto usable = [&](int r, int c) {
    return usable_fixed(r, c) && std::isfinite(moving.at(r, c)) && moving_valid.at(r, c) != 0;
  };
  double flo = 1e300, fhi = -1e300, mlo = 1e300, mhi = -1e300;
  int n = 0;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      if (usable_fixed(r, c)) flo = std::min(flo, double(fixed.at(r, c))), fhi = std::max(fhi, double(fixed.at(r, c)));
      if (!usable(r, c)) continue;
      mlo = std::min(mlo, double(moving.at(r, c)));
      mhi = std::max(mhi, double(moving.at(r, c)));
      ++n;
    }
  std::vector<double> joint(std::size_t(bins) * bins, 0.0), pf(bins, 0.0), pm(bins, 0.0);
  const double fscale = (bins - 1e-9) / (fhi - flo), mscale = (bins - 1) / (mhi - mlo);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      if (!usable(r, c)) continue;
      const int a = std::clamp(int((fixed.at(r, c) - flo) * fscale), 0, bins - 1);
      const double x = (moving.at(r, c) - mlo) * mscale;
      const int j = std::min(int(x), bins - 2);
      const double w = x - j;
      joint[std::size_t(a) * bins + j] += 1 - w;
      joint[std::size_t(a) * bins + j + 1] += w;
    }
  for (int a = 0; a < bins; ++a)
    for (int b = 0; b < bins; ++b) pf[a] += joint[std::size_t(a) * bins + b], pm[b] += joint[std::size_t(a) * bins + b];
  auto entropy = [&](const std::vector<double>& k) {
    double h = 0;
    for (double v : k)
      if (v > 0) h -= v / n * std::log(v / n);
    return h;
  };
  const double hf = entropy(pf), hm = entropy(pm), hj = entropy(joint);
  return normalised ? (hf + hm) / hj : hf + hm - hj;
}

struct Case {
  int rows, cols, bins;
};

class MutualInformationAgainstReference : public ::testing::TestWithParam<Case> {};

TEST_P(MutualInformationAgainstReference, AgreesWithinRounding) {
  const Case k = GetParam();
  std::mt19937 rng(k.rows * 31 + k.cols);
  std::normal_distribution<float> noise(0.f, 0.3f);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  Image<float> fixed(k.rows, k.cols), moving(k.rows, k.cols);
  Image<unsigned char> fixed_valid(k.rows, k.cols, 1), moving_valid(k.rows, k.cols, 1);
  for (int r = 0; r < k.rows; ++r)
    for (int c = 0; c < k.cols; ++c) {
      const float anatomy = 3.f * std::sin(0.11f * float(c)) * std::cos(0.07f * float(r)) + (c > k.cols / 3 ? 2.f : 0.f);
      fixed.at(r, c) = anatomy + noise(rng);
      moving.at(r, c) = 0.7f * anatomy + 5.f + noise(rng);
      if (u(rng) < 0.05f) fixed_valid.at(r, c) = 0;
      if (u(rng) < 0.05f) moving_valid.at(r, c) = 0;
      if (u(rng) < 0.01f) moving.at(r, c) = u(rng) < 0.5f ? std::numeric_limits<float>::quiet_NaN()
                                                          : std::numeric_limits<float>::infinity();
      if (u(rng) < 0.01f) fixed.at(r, c) = u(rng) < 0.5f ? std::numeric_limits<float>::quiet_NaN()
                                                         : -std::numeric_limits<float>::infinity();
    }
  for (const bool normalised : {false, true}) {
    SimilarityOptions options;
    options.histogram_bins = k.bins;
    auto mi = std::move(make_similarity(normalised ? "nmi" : "mi", options)).value();
    ASSERT_TRUE(mi->prepare(fixed.view(), fixed_valid.view()).ok());
    const double got = mi->score(moving.view(), moving_valid.view());
    const double want = reference_mi(fixed, fixed_valid, moving, moving_valid, k.bins, normalised);
    EXPECT_NEAR(got, want, 1e-5 * std::abs(want)) << (normalised ? "nmi " : "mi ") << k.rows << " x " << k.cols;
    // The same again: the scratch is reset between scores.
    EXPECT_EQ(mi->score(moving.view(), moving_valid.view()), got);
    // The portable loops give the same score bit for bit, with a mask and without.
    options.vector_lanes = false;
    auto portable = std::move(make_similarity(normalised ? "nmi" : "mi", options)).value();
    ASSERT_TRUE(portable->prepare(fixed.view(), fixed_valid.view()).ok());
    EXPECT_EQ(portable->score(moving.view(), moving_valid.view()), got);
    EXPECT_EQ(portable->score(moving.view(), {}), mi->score(moving.view(), {}));
  }
}

// The real-CT window, its 2 x 2 binned level, a detector larger than 2^16 pixels (fewer weight
// bits, so that no sub-histogram cell can overflow), and the images on either side of
// kMiManyPixels (4,096: one histogram up to it, four sub-histograms beyond).
INSTANTIATE_TEST_SUITE_P(Sizes, MutualInformationAgainstReference,
                         ::testing::Values(Case{144, 316, 64}, Case{72, 158, 64}, Case{512, 512, 64},
                                           Case{7, 9, 2}, Case{40, 33, 1024}, Case{64, 64, 64},
                                           Case{64, 65, 64}));

}  // namespace
}  // namespace lftrack::tracking
