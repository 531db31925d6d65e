// Numerical stability at the extremes: images and similarity (docs/stability.md, "Images and
// similarity"). Every measure returns a finite score for every image, or its worst score where
// nothing can be compared; preprocessing masks what it cannot turn into a line integral.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>

#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/similarity.hpp"

namespace lftrack::tracking {
namespace {

Image<float> ramp(int rows, int cols) {
  Image<float> im(rows, cols);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) im.at(r, c) = float(0.5 + 0.3 * std::sin(0.3 * r) + 0.02 * c);
  return im;
}

// The score of `moving` against `fixed` for measure `name` (prepare's failure: NaN, so callers
// can tell).
double score(const std::string& name, const Image<float>& fixed, const Image<float>& moving, int bins = 64) {
  SimilarityOptions options;
  options.histogram_bins = bins;
  auto m = make_similarity(name, options);
  EXPECT_TRUE(m.ok());
  if (!(*m)->prepare(fixed.view(), {}).ok()) return std::nan("");
  return (*m)->score(moving.view());
}

double worst(const std::string& name) {
  return (*make_similarity(name))->worst_score();
}

class MeasureAtTheExtremes : public ::testing::TestWithParam<std::string> {};

TEST_P(MeasureAtTheExtremes, ConstantAndAllZeroImagesScoreFinite) {
  const std::string name = GetParam();
  const Image<float> constant(32, 32, 0.7f), zero(32, 32, 0.0f), textured = ramp(32, 32);
  for (const auto* pair : {&constant, &zero}) {
    EXPECT_TRUE(std::isfinite(score(name, *pair, textured))) << name;
    EXPECT_TRUE(std::isfinite(score(name, textured, *pair))) << name;
    EXPECT_TRUE(std::isfinite(score(name, *pair, *pair))) << name;
  }
}

TEST_P(MeasureAtTheExtremes, SaturatedImagesScoreFinite) {
  const std::string name = GetParam();
  Image<float> saturated = ramp(32, 32);
  for (int r = 0; r < 32; ++r)
    for (int c = 0; c < 20; ++c) saturated.at(r, c) = 3.0e38f;  // clipped at the top of float
  EXPECT_TRUE(std::isfinite(score(name, saturated, ramp(32, 32)))) << name;
  EXPECT_TRUE(std::isfinite(score(name, ramp(32, 32), saturated))) << name;
}

TEST_P(MeasureAtTheExtremes, ImagesSpanningTheWholeFloatRangeScoreFinite) {
  // Differences between pixels overflow a float (6e38 > 3.4e38): mutual information's bins must
  // not come from an infinite position (clang's UBSan checks the conversions in build-fuzz).
  const std::string name = GetParam();
  Image<float> span = ramp(32, 32);
  for (int r = 0; r < 32; ++r) {
    span.at(r, 0) = -3.0e38f;
    span.at(r, 31) = 3.0e38f;
  }
  for (const auto& [fixed, moving] : {std::pair{&span, &span}, {&span, nullptr}, {nullptr, &span}}) {
    const Image<float> plain = ramp(32, 32);
    const double s = score(name, fixed ? *fixed : plain, moving ? *moving : plain);
    EXPECT_TRUE(std::isfinite(s)) << name;
  }
}

TEST_P(MeasureAtTheExtremes, SinglePixelImagesGiveTheWorstScore) {
  const std::string name = GetParam();
  const Image<float> one(1, 1, 0.5f);
  const double s = score(name, one, one);
  EXPECT_TRUE(std::isnan(s) || s == worst(name)) << name << ": " << s;  // refused or worst
  auto m = make_similarity(name);
  ASSERT_TRUE((*m)->prepare(ramp(32, 32).view(), {}).ok());
  EXPECT_EQ((*m)->score(one.view()), worst(name)) << "a moving image of another size";
}

TEST_P(MeasureAtTheExtremes, NanPixelsAreLeftOutNotPropagated) {
  const std::string name = GetParam();
  Image<float> holes = ramp(32, 32);
  holes.at(3, 4) = std::nanf("");
  holes.at(10, 10) = std::numeric_limits<float>::infinity();
  const double fixed_holes = score(name, holes, ramp(32, 32));
  const double moving_holes = score(name, ramp(32, 32), holes);
  EXPECT_TRUE(std::isfinite(fixed_holes)) << name;
  EXPECT_TRUE(std::isfinite(moving_holes)) << name;
  Image<float> all_nan(32, 32, std::nanf(""));
  const double s = score(name, ramp(32, 32), all_nan);
  EXPECT_EQ(s, worst(name)) << name;
}

INSTANTIATE_TEST_SUITE_P(Stability, MeasureAtTheExtremes, ::testing::ValuesIn(similarity_names()),
                         [](const auto& p) { return p.param; });

TEST(StabilitySimilarity, MutualInformationWith2And1024Bins) {
  const Image<float> a = ramp(64, 64);
  Image<float> b = ramp(64, 64);
  for (float& v : b.pixels()) v = 2 * v + 1;
  for (const char* name : {"mi", "nmi"}) {
    for (int bins : {2, 1024}) {
      const double self = score(name, a, a, bins), mapped = score(name, a, b, bins);
      EXPECT_TRUE(std::isfinite(self) && std::isfinite(mapped)) << name << " " << bins;
      EXPECT_GE(self, 0.0);
    }
  }
  // MI of an image with itself is its entropy: at most ln(bins).
  EXPECT_LE(score("mi", a, a, 2), std::log(2.0) + 1e-9);
  SimilarityOptions one_bin;
  one_bin.histogram_bins = 1;
  auto refused = make_similarity("mi", one_bin);
  ASSERT_FALSE(refused.ok()) << "1 bin measures nothing";
  EXPECT_NE(refused.status().message().find("2..1024"), std::string::npos);
  one_bin.histogram_bins = 1025;
  EXPECT_FALSE(make_similarity("nmi", one_bin).ok());
}

// Preprocessing: starved, saturated, dead and NaN-gain pixels are masked with p = 0.
TEST(StabilityImages, PreprocessingMasksWhatHasNoLineIntegral) {
  Image<std::uint16_t> raw(4, 4, std::uint16_t{2000});
  raw.at(0, 0) = 0;      // no photons
  raw.at(0, 1) = 4095;   // saturated
  raw.at(0, 2) = 65535;  // beyond the detector's range
  DetectorCorrection correction;
  correction.gain = Image<float>(4, 4, 1.0f);
  correction.gain.at(1, 0) = 0.0f;           // dead
  correction.gain.at(1, 1) = std::nanf("");  // a corrupt gain map
  correction.gain.at(1, 2) = std::numeric_limits<float>::infinity();
  Image<float> p(4, 4);
  Image<unsigned char> valid(4, 4);
  ASSERT_TRUE(preprocess_frame(raw.view(), correction, PixelWindow::full(4, 4), p.view(), valid.view()).ok());
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      ASSERT_TRUE(std::isfinite(p.at(r, c))) << r << "," << c;
      if (!valid.at(r, c)) {
        EXPECT_EQ(p.at(r, c), 0.0f);
      }
    }
  for (auto [r, c] : {std::pair{0, 0}, {0, 1}, {0, 2}, {1, 0}, {1, 1}, {1, 2}})
    EXPECT_EQ(valid.at(r, c), 0) << r << c;
  EXPECT_EQ(valid.at(3, 3), 1);
  DetectorCorrection bad_i0;
  bad_i0.open_field_counts = std::nan("");
  EXPECT_FALSE(preprocess_frame(raw.view(), bad_i0, PixelWindow::full(4, 4), p.view(), valid.view()).ok());
}

}  // namespace
}  // namespace lftrack::tracking
