// The image-quality gate's checks, each on the frame that should trip it, and a frame with
// anatomy and photon noise that should pass.

#include "lftrack/tracking/frame_quality.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

namespace lftrack::tracking {
namespace {

DetectorCorrection detector() {
  DetectorCorrection d;
  d.open_field_counts = 4000;
  d.saturation_counts = 4095;
  return d;
}

// Anatomy: a smooth attenuation bump across the frame, with Poisson-like noise.
Image<std::uint16_t> anatomy(int rows = 64, int cols = 80) {
  Image<std::uint16_t> f(rows, cols);
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0, 1);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const double x = (c - cols / 2.0) / cols, y = (r - rows / 2.0) / rows;
      const double counts = 4000 * std::exp(-2.0 * std::exp(-8 * (x * x + y * y)));
      f.at(r, c) = static_cast<std::uint16_t>(std::lround(counts + std::sqrt(counts) * noise(rng)));
    }
  return f;
}

FrameQualityIssue assess(const Image<std::uint16_t>& f, FrameQualityStats* s = nullptr) {
  return assess_frame_quality(f.view(), PixelWindow{0, 0, f.rows(), f.cols()}, detector(), {}, s);
}

TEST(FrameQuality, AFrameWithAnatomyPasses) {
  FrameQualityStats s;
  EXPECT_EQ(assess(anatomy(), &s), FrameQualityIssue::kOk);
  EXPECT_GT(s.relative_spread, 0.1);
  EXPECT_EQ(s.saturated_fraction, 0);
}

TEST(FrameQuality, EachBadFrameGetsItsReason) {
  Image<std::uint16_t> f = anatomy();
  std::fill(f.pixels().begin(), f.pixels().end(), std::uint16_t(4095));
  EXPECT_EQ(assess(f), FrameQualityIssue::kSaturated);
  std::fill(f.pixels().begin(), f.pixels().end(), std::uint16_t(0));
  EXPECT_EQ(assess(f), FrameQualityIssue::kBlank);
  std::fill(f.pixels().begin(), f.pixels().end(), std::uint16_t(5));  // a trickle of dark current: no exposure
  EXPECT_EQ(assess(f), FrameQualityIssue::kBlank);
  std::fill(f.pixels().begin(), f.pixels().end(), std::uint16_t(2500));
  EXPECT_EQ(assess(f), FrameQualityIssue::kUniform);
  // Open field with photon noise only: still no anatomy.
  std::mt19937 rng(1);
  std::normal_distribution<double> noise(4000, 63);
  for (int r = 0; r < f.rows(); ++r)
    for (int c = 0; c < f.cols(); ++c) f.at(r, c) = static_cast<std::uint16_t>(std::lround(noise(rng)));
  EXPECT_EQ(assess(f), FrameQualityIssue::kUniform);
  f = anatomy();
  for (int r = 0; r < f.rows(); r += 2)
    for (int c = 0; c < f.cols(); c += 4) f.at(r, c) = 0;  // 12.5 % dead
  EXPECT_EQ(assess(f), FrameQualityIssue::kDeadPixels);
  f = anatomy();
  for (int r = 0; r < f.rows() / 2; ++r)
    for (int c = 0; c < f.cols(); ++c) f.at(r, c) = 4095;  // half over-exposed
  EXPECT_EQ(assess(f), FrameQualityIssue::kSaturated);
}

// Blank is judged on the detector's range, not on the open field: thick anatomy an automatic
// exposure control exposed well passes even though it transmits a thousandth of the open field (the
// old rule called a real abdomen's oblique view blank at any dose), a ROI near the bottom of the
// range does not, and neither does a frame at the detector's dark level, however high that is.
TEST(FrameQuality, BlankIsARoiAPersonSeesAsBlackNotThickAnatomy) {
  DetectorCorrection aec = detector();
  aec.open_field_counts = 400'000;  // the open field at 100 x full scale: it saturates
  Image<std::uint16_t> thick = anatomy();
  for (std::uint16_t& v : thick.pixels()) v = static_cast<std::uint16_t>(v / 10);  // ROI mean near 200 counts
  const PixelWindow all{0, 0, thick.rows(), thick.cols()};
  FrameQualityStats s;
  EXPECT_EQ(assess_frame_quality(thick.view(), all, aec, {}, &s), FrameQualityIssue::kOk);
  EXPECT_LT(s.mean_counts, 0.002 * aec.open_field_counts) << "well under the old open-field floor";
  Image<std::uint16_t> starved = anatomy();
  for (std::uint16_t& v : starved.pixels()) v = static_cast<std::uint16_t>(v / 150);  // a mean near 14 counts
  EXPECT_EQ(assess_frame_quality(starved.view(), all, aec, {}, &s), FrameQualityIssue::kBlank);
  EXPECT_LT(s.mean_counts, 0.01 * 4095);
  // The tube off on a panel whose dark level is 300 counts: only the dark level, with read noise.
  DetectorCorrection offset = detector();
  offset.dark_counts = Image<float>(thick.rows(), thick.cols(), 300.f);
  Image<std::uint16_t> dark(thick.rows(), thick.cols());
  std::mt19937 rng(5);
  std::normal_distribution<double> read_noise(300, 12);
  for (std::uint16_t& v : dark.pixels()) v = static_cast<std::uint16_t>(std::lround(read_noise(rng)));
  EXPECT_EQ(assess_frame_quality(dark.view(), all, offset, {}, &s), FrameQualityIssue::kBlank);
  EXPECT_LT(std::abs(s.mean_counts), 5.0) << "the signal is what is above the dark level";
}

TEST(FrameQuality, OnlyTheWindowCountsAndAnEmptyWindowIsBlank) {
  Image<std::uint16_t> f = anatomy();
  for (int r = 0; r < f.rows(); ++r)
    for (int c = 0; c < 20; ++c) f.at(r, c) = 4095;  // saturated outside the window
  EXPECT_EQ(assess_frame_quality(f.view(), PixelWindow{0, 20, f.rows(), 60}, detector(), {}),
            FrameQualityIssue::kOk);
  EXPECT_EQ(assess_frame_quality(f.view(), PixelWindow{100, 100, 10, 10}, detector(), {}),
            FrameQualityIssue::kBlank);
  EXPECT_STREQ(to_string(FrameQualityIssue::kDeadPixels), "dead pixels");
}

}  // namespace
}  // namespace lftrack::tracking
