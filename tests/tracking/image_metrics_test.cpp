#include <gtest/gtest.h>

#include <cmath>

#include "lftrack/tracking/image_metrics.hpp"

namespace lftrack::tracking {
namespace {

Image<float> pattern(int n, float scale, float offset) {
  Image<float> im(n, n);
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c)
      im.at(r, c) = scale * std::sin(0.3f * float(r)) * std::cos(0.2f * float(c)) + offset;
  return im;
}

TEST(Ncc, InvariantToPositiveLinearMaps) {
  const Image<float> a = pattern(32, 1.0f, 0.0f);
  const Image<float> b = pattern(32, 3.5f, 10.0f);
  EXPECT_NEAR(normalized_cross_correlation(a.view(), b.view()), 1.0, 1e-6);
  const Image<float> inverted = pattern(32, -2.0f, 1.0f);
  EXPECT_NEAR(normalized_cross_correlation(a.view(), inverted.view()), -1.0, 1e-6);
}

TEST(Ncc, DefinedOnDegenerateInputs) {
  const Image<float> flat(8, 8, 2.0f);
  const Image<float> other(8, 8, 3.0f);
  EXPECT_EQ(normalized_cross_correlation(flat.view(), flat.view()), 1.0);
  EXPECT_EQ(normalized_cross_correlation(flat.view(), other.view()), 0.0);
  Image<float> with_nan = pattern(8, 1, 0);
  with_nan.at(3, 3) = std::nanf("");
  EXPECT_TRUE(std::isnan(normalized_cross_correlation(with_nan.view(), pattern(8, 1, 0).view())));
  EXPECT_TRUE(
      std::isnan(normalized_cross_correlation(flat.view(), pattern(9, 1, 0).view())));  // size mismatch
}

TEST(Ncc, MaskExcludesPixels) {
  Image<float> a = pattern(16, 1, 0), b = pattern(16, 1, 0);
  b.at(0, 0) = 100.0f;
  Image<unsigned char> mask(16, 16, 1);
  mask.at(0, 0) = 0;
  const ImageView<const unsigned char> mv = mask.view();
  EXPECT_NEAR(normalized_cross_correlation(a.view(), b.view(), &mv), 1.0, 1e-9);
  EXPECT_LT(normalized_cross_correlation(a.view(), b.view()), 0.99);
}

TEST(Psnr, KnownValue) {
  Image<float> ref(4, 4, 0.0f), test(4, 4, 0.0f);
  ref.at(0, 0) = 10.0f;
  test.at(0, 0) = 10.0f;
  test.at(1, 1) = 1.0f;  // MSE = 1/16, peak 10
  EXPECT_NEAR(psnr_db(ref.view(), test.view()), 20 * std::log10(10.0 / 0.25), 1e-9);
  EXPECT_TRUE(std::isinf(psnr_db(ref.view(), ref.view())));
}

}  // namespace
}  // namespace lftrack::tracking
