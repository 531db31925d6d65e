#include "lftrack/tracking/frame_preprocessing.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace lftrack::tracking {
namespace {

TEST(PreprocessFrame, LogOfOpenFieldOverCorrectedIntensity) {
  Image<std::uint16_t> raw(4, 6, 1000);
  raw.at(1, 2) = 4095;  // saturated
  raw.at(2, 3) = 0;     // photon-starved
  raw.at(3, 4) = 500;
  DetectorCorrection c;
  c.open_field_counts = 3000;
  c.dark_counts = Image<float>(4, 6, 100.f);
  c.gain = Image<float>(4, 6, 1.f);
  c.gain.at(0, 5) = 0.f;  // dead
  c.gain.at(3, 4) = 2.f;
  const PixelWindow window{0, 1, 4, 5};
  Image<float> p(4, 5);
  Image<unsigned char> valid(4, 5);
  ASSERT_TRUE(preprocess_frame(raw.view(), c, window, p.view(), valid.view()).ok());
  EXPECT_NEAR(p.at(0, 0), std::log(3000.0 / 900.0), 1e-6);
  EXPECT_NEAR(p.at(3, 3), std::log(3000.0 / 200.0), 1e-6);  // (500 - 100) / 2
  EXPECT_EQ(valid.at(1, 1), 0);
  EXPECT_EQ(valid.at(2, 2), 0);
  EXPECT_EQ(valid.at(0, 4), 0);
  EXPECT_EQ(p.at(1, 1), 0.f);
  EXPECT_EQ(valid.at(0, 0), 1);
}

// Every raw value a 16-bit detector can give, with and without dark and gain images: the float
// log the cycle uses against p = ln(I0 / I) in double, and the same mask.
TEST(PreprocessFrame, EveryRawValueMatchesTheFormulaInDouble) {
  Image<std::uint16_t> raw(256, 256);
  for (int i = 0; i < 65536; ++i) raw.at(i / 256, i % 256) = static_cast<std::uint16_t>(i);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> dark_of(-5.f, 60.f), gain_of(0.5f, 1.6f);
  for (const bool corrected : {false, true}) {
    DetectorCorrection c;
    c.open_field_counts = 30000;
    c.saturation_counts = 65000;
    if (corrected) {
      c.dark_counts = Image<float>(256, 256);
      c.gain = Image<float>(256, 256);
      for (float& d : c.dark_counts.pixels()) d = dark_of(rng);
      for (float& g : c.gain.pixels()) g = gain_of(rng);
      c.gain.at(7, 7) = 0.f;      // dead
      c.gain.at(8, 8) = 1e38f;    // I0 / I past float's range: masked, not infinite
      c.dark_counts.at(9, 9) = std::numeric_limits<float>::quiet_NaN();
    }
    Image<float> p(256, 256);
    Image<unsigned char> valid(256, 256);
    ASSERT_TRUE(preprocess_frame(raw.view(), c, {0, 0, 256, 256}, p.view(), valid.view()).ok());
    int usable = 0;
    for (int r = 0; r < 256; ++r)
      for (int col = 0; col < 256; ++col) {
        const double counts = raw.at(r, col);
        const double dark = corrected ? c.dark_counts.at(r, col) : 0.0;
        const double gain = corrected ? c.gain.at(r, col) : 1.0;
        const double intensity = gain > 0 ? (counts - dark) / gain : 0.0;
        const double expected = std::log(c.open_field_counts / intensity);
        const bool ok = counts < c.saturation_counts && gain > 0 && intensity > 0 && std::isfinite(expected) &&
                        c.open_field_counts / intensity < std::numeric_limits<float>::max();
        ASSERT_EQ(valid.at(r, col), ok ? 1 : 0) << r << " " << col << " corrected " << corrected;
        ASSERT_TRUE(std::isfinite(p.at(r, col)));
        if (!ok) {
          ASSERT_EQ(p.at(r, col), 0.f) << r << " " << col;
          continue;
        }
        ++usable;
        ASSERT_NEAR(p.at(r, col), expected, 1e-6 * std::max(1.0, std::abs(expected))) << r << " " << col;
      }
    EXPECT_GT(usable, 64000) << corrected;
  }
}

TEST(PreprocessFrame, RefusesBadSizesAndLevels) {
  Image<std::uint16_t> raw(4, 6, 1000);
  Image<float> p(4, 5);
  Image<unsigned char> valid(4, 5);
  DetectorCorrection c;
  EXPECT_FALSE(preprocess_frame(raw.view(), c, {0, 2, 4, 5}, p.view(), valid.view()).ok());  // outside
  EXPECT_FALSE(preprocess_frame(raw.view(), c, {0, 0, 4, 4}, p.view(), valid.view()).ok());  // output size
  c.dark_counts = Image<float>(3, 3, 0.f);
  EXPECT_FALSE(preprocess_frame(raw.view(), c, {0, 0, 4, 5}, p.view(), valid.view()).ok());
  c.dark_counts = {};
  for (double i0 : {0.0, -1.0, 1e-300, 1e300, std::numeric_limits<double>::quiet_NaN(),
                    std::numeric_limits<double>::infinity()}) {
    c.open_field_counts = i0;  // in float, 1e-300 would give ln(0) and 1e300 ln(inf)
    EXPECT_FALSE(preprocess_frame(raw.view(), c, {0, 0, 4, 5}, p.view(), valid.view()).ok()) << i0;
  }
}

// Absurd corrections at the edges of float's range: the pixel is masked and p stays finite.
TEST(PreprocessFrame, AbsurdGainsAndLevelsGiveNoInfiniteLineIntegral) {
  Image<std::uint16_t> raw(2, 3, 65000);
  raw.at(0, 0) = 1;
  for (const double i0 : {1e-20, 1e30}) {
    DetectorCorrection c;
    c.open_field_counts = i0;
    c.saturation_counts = 65535;
    c.gain = Image<float>(2, 3, 1.f);
    c.gain.at(0, 1) = 1e-38f;  // I0 / I underflows
    c.gain.at(0, 2) = 1e38f;   // I0 / I overflows
    Image<float> p(2, 3);
    Image<unsigned char> valid(2, 3);
    ASSERT_TRUE(preprocess_frame(raw.view(), c, {0, 0, 2, 3}, p.view(), valid.view()).ok()) << i0;
    for (float v : p.pixels()) EXPECT_TRUE(std::isfinite(v)) << i0;
    c.gain = {};  // and without a gain image, every raw value from 1 to the saturation
    ASSERT_TRUE(preprocess_frame(raw.view(), c, {0, 0, 2, 3}, p.view(), valid.view()).ok()) << i0;
    for (float v : p.pixels()) EXPECT_TRUE(std::isfinite(v)) << i0;
    EXPECT_EQ(valid.at(0, 0), 1) << i0;
  }
}

TEST(GaussianBlur, KeepsConstantsRespectsMasksAndCopiesAtZeroSigma) {
  Image<float> in(20, 30, 2.f);
  Image<unsigned char> mask(20, 30, 1);
  in.at(10, 10) = 1000.f;  // a masked outlier must not leak into its neighbours
  mask.at(10, 10) = 0;
  Image<float> out(20, 30);
  GaussianBlur blur(20, 30, 2.0);
  ASSERT_TRUE(blur.blur(in.view(), mask.view(), out.view()).ok());
  EXPECT_NEAR(out.at(10, 11), 2.f, 1e-5);
  EXPECT_NEAR(out.at(0, 0), 2.f, 1e-5);
  EXPECT_EQ(out.at(10, 10), 1000.f);  // masked pixels keep their value
  GaussianBlur none(20, 30, 0.0);
  ASSERT_TRUE(none.blur(in.view(), {}, out.view()).ok());
  EXPECT_EQ(out.at(10, 10), 1000.f);
  Image<float> wrong(5, 5);
  EXPECT_FALSE(blur.blur(wrong.view(), {}, out.view()).ok());
}

TEST(GaussianBlur, SpreadsAnImpulseWithTheRequestedSigma) {
  Image<float> in(41, 41, 0.f), out(41, 41);
  in.at(20, 20) = 1.f;
  GaussianBlur blur(41, 41, 3.0);
  ASSERT_TRUE(blur.blur(in.view(), {}, out.view()).ok());
  double sum = 0, second_moment = 0;
  for (int r = 0; r < 41; ++r)
    for (int c = 0; c < 41; ++c) {
      sum += out.at(r, c);
      second_moment += double(out.at(r, c)) * (c - 20) * (c - 20);
    }
  EXPECT_NEAR(sum, 1.0, 1e-3);
  EXPECT_NEAR(std::sqrt(second_moment / sum), 3.0, 0.05);
}

// The high-pass keeps an impulse's energy at the impulse and takes out what varies slowly: a
// constant and a plane vanish away from the borders (a symmetric box's mean of a plane is its centre
// value), and its low-pass part has the requested standard deviation.
TEST(BoxHighPass, RemovesPlanesKeepsImpulsesAndHasTheRequestedSigma) {
  const int n = 61;
  Image<float> plane(n, n), out(n, n);
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) plane.at(r, c) = 5.f + 0.3f * float(r) - 0.2f * float(c);
  const double sigma = std::sqrt(12.0);  // three boxes of 7 pixels exactly
  const int radius = BoxHighPass::radius_for_sigma(sigma);
  ASSERT_EQ(radius, 3);
  BoxHighPass highpass(n, n, radius);
  ASSERT_TRUE(highpass.apply(plane.view(), {}, out.view()).ok());
  const int margin = BoxHighPass::kPasses * radius;
  for (int r = margin; r < n - margin; ++r)
    for (int c = margin; c < n - margin; ++c) ASSERT_NEAR(out.at(r, c), 0.f, 1e-4) << r << "," << c;
  Image<float> impulse(n, n, 0.f);
  impulse.at(30, 30) = 1.f;
  ASSERT_TRUE(highpass.apply(impulse.view(), {}, out.view()).ok());
  // out = impulse - low; low sums to 1 and spreads with the requested sigma.
  double low_sum = 0, second_moment = 0;
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) {
      const double low = impulse.at(r, c) - out.at(r, c);
      low_sum += low;
      second_moment += low * (c - 30) * (c - 30);
    }
  EXPECT_NEAR(low_sum, 1.0, 1e-4);
  EXPECT_NEAR(std::sqrt(second_moment / low_sum), sigma, 0.02);
  EXPECT_GT(out.at(30, 30), 0.9f);
}

TEST(BoxHighPass, MaskedPixelsNeitherContributeNorReceiveAndInPlaceMatches) {
  Image<float> in(20, 30, 2.f);
  Image<unsigned char> mask(20, 30, 1);
  in.at(10, 10) = 1000.f;
  mask.at(10, 10) = 0;
  in.at(3, 3) = std::nanf("");
  Image<float> out(20, 30);
  BoxHighPass highpass(20, 30, 3);
  ASSERT_TRUE(highpass.apply(in.view(), mask.view(), out.view()).ok());
  EXPECT_EQ(out.at(10, 10), 0.f);
  EXPECT_EQ(out.at(3, 3), 0.f);  // not finite: masked
  EXPECT_NEAR(out.at(10, 11), 0.f, 1e-5);  // the outlier did not leak
  for (int r = 0; r < 20; ++r)
    for (int c = 0; c < 30; ++c) ASSERT_TRUE(std::isfinite(out.at(r, c)));
  Image<float> same = in;
  ASSERT_TRUE(highpass.apply(same.view(), mask.view(), same.view()).ok());
  for (int r = 0; r < 20; ++r)
    for (int c = 0; c < 30; ++c) ASSERT_EQ(same.at(r, c), out.at(r, c));
  Image<float> wrong(5, 5);
  EXPECT_FALSE(highpass.apply(wrong.view(), {}, out.view()).ok());
  Image<unsigned char> wrong_mask(5, 5, 1);
  EXPECT_FALSE(highpass.apply(in.view(), wrong_mask.view(), out.view()).ok());
  for (double sigma : {0.0, -1.0, std::nan(""), 1e12, HUGE_VAL}) {
    const int r = BoxHighPass::radius_for_sigma(sigma);
    EXPECT_GE(r, 1) << sigma;
    EXPECT_LE(r, 20000) << sigma;
  }
  BoxHighPass tiny(1, 1, 0);  // a radius below 1 is raised; a 1 x 1 image high-passes to 0
  Image<float> one(1, 1, 7.f), one_out(1, 1);
  ASSERT_TRUE(tiny.apply(one.view(), {}, one_out.view()).ok());
  EXPECT_EQ(tiny.radius_px(), 1);
  EXPECT_EQ(one_out.at(0, 0), 0.f);
}

// The filter against the definition, computed the slow way: kPasses times, each usable pixel
// becomes the mean of the usable pixels in its box. Random images, random masks (including a
// fully masked row and column), several radii and a box wider than the image; then the same
// filter object on another mask (its kept counts must not be reused) and on the first again.
std::vector<float> slow_high_pass(const Image<float>& in, const Image<unsigned char>& mask, int radius) {
  const int rows = in.rows(), cols = in.cols();
  auto usable = [&](int r, int c) { return std::isfinite(in.at(r, c)) && mask.at(r, c) != 0; };
  std::vector<double> low(std::size_t(rows * cols));
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) low[std::size_t(r * cols + c)] = usable(r, c) ? in.at(r, c) : 0.0;
  for (int pass = 0; pass < BoxHighPass::kPasses; ++pass) {
    std::vector<double> next(low.size(), 0.0);
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) {
        if (!usable(r, c)) continue;
        double sum = 0, n = 0;
        for (int rr = std::max(0, r - radius); rr <= std::min(rows - 1, r + radius); ++rr)
          for (int cc = std::max(0, c - radius); cc <= std::min(cols - 1, c + radius); ++cc)
            if (usable(rr, cc)) sum += low[std::size_t(rr * cols + cc)], n += 1;
        next[std::size_t(r * cols + c)] = sum / n;
      }
    low = next;
  }
  std::vector<float> out(low.size());
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
      out[std::size_t(r * cols + c)] = usable(r, c) ? float(in.at(r, c) - low[std::size_t(r * cols + c)]) : 0.f;
  return out;
}

TEST(BoxHighPass, EqualsTheDefinitionComputedSlowlyForAnyMaskAndRadius) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> value(0.f, 8.f), unit(0.f, 1.f);
  const int rows = 23, cols = 37;
  auto random_mask = [&](float keep) {
    Image<unsigned char> m(rows, cols, 1);
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) m.at(r, c) = unit(rng) < keep ? 1 : 0;
    for (int c = 0; c < cols; ++c) m.at(4, c) = 0;  // a masked row
    for (int r = 0; r < rows; ++r) m.at(r, 9) = 0;  // and column
    return m;
  };
  for (const int radius : {1, 2, 5, 40}) {
    Image<float> in(rows, cols);
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) in.at(r, c) = value(rng);
    in.at(7, 7) = std::nanf("");
    const Image<unsigned char> first = random_mask(0.8f), second = random_mask(0.5f);
    BoxHighPass highpass(rows, cols, radius);
    Image<float> out(rows, cols);
    for (const Image<unsigned char>* mask : {&first, &first, &second, &first}) {
      ASSERT_TRUE(highpass.apply(in.view(), mask->view(), out.view()).ok());
      const std::vector<float> expected = slow_high_pass(in, *mask, highpass.radius_px());
      // A filter that kept the last call's counts gives the bits of a fresh one.
      BoxHighPass fresh(rows, cols, radius);
      Image<float> fresh_out(rows, cols);
      ASSERT_TRUE(fresh.apply(in.view(), mask->view(), fresh_out.view()).ok());
      for (int r = 0; r < rows; ++r)
        for (int c = 0; c < cols; ++c) {
          ASSERT_NEAR(out.at(r, c), expected[std::size_t(r * cols + c)], 2e-5)
              << "radius " << radius << " at " << r << "," << c;
          ASSERT_EQ(out.at(r, c), fresh_out.at(r, c)) << "radius " << radius << " at " << r << "," << c;
        }
    }
  }
}

}  // namespace
}  // namespace lftrack::tracking
