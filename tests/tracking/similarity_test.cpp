// Every similarity measure, through the factory, on the same fixtures (DESIGN.md test level 2).

#include "lftrack/tracking/similarity.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>

#include "fixtures.hpp"
#include "lftrack/tracking/drr_renderer.hpp"

namespace lftrack::tracking {
namespace {

// A DRR of the fixture volume: a textured image with edges, 48 x 40.
const Image<float>& fixture_drr() {
  static const Image<float> image = [] {
    const XrayView view = test::fixture_view();
    Image<float> out(view.rows, view.cols);
    auto renderer = make_renderer("siddon", test::fixture_volume());
    EXPECT_TRUE((*renderer)->render(Pose::Identity(), view, PixelWindow::full(view.rows, view.cols), out.view()).ok());
    return out;
  }();
  return image;
}

// The fixture shifted by (dx, dy) pixels (bilinear; edges clamped).
Image<float> shifted(const Image<float>& in, double dx, double dy) {
  Image<float> out(in.rows(), in.cols());
  for (int r = 0; r < in.rows(); ++r)
    for (int c = 0; c < in.cols(); ++c) {
      const double x = std::clamp(c - dx, 0.0, in.cols() - 1.0), y = std::clamp(r - dy, 0.0, in.rows() - 1.0);
      const int x0 = std::min(int(x), in.cols() - 2), y0 = std::min(int(y), in.rows() - 2);
      const double fx = x - x0, fy = y - y0;
      out.at(r, c) = float((1 - fy) * ((1 - fx) * in.at(y0, x0) + fx * in.at(y0, x0 + 1)) +
                           fy * ((1 - fx) * in.at(y0 + 1, x0) + fx * in.at(y0 + 1, x0 + 1)));
    }
  return out;
}

class EverySimilarity : public ::testing::TestWithParam<std::string> {
 protected:
  std::unique_ptr<Similarity> make() {
    SimilarityOptions options;
    options.histogram_bins = 32;
    auto s = make_similarity(GetParam(), options);
    EXPECT_TRUE(s.ok()) << s.status().message();
    return std::move(s).value();
  }
};

TEST_P(EverySimilarity, IdentityScoresHighestAndScoresFallWithMisalignment) {
  auto s = make();
  ASSERT_TRUE(s->prepare(fixture_drr().view(), {}).ok());
  const double at_identity = s->score(fixture_drr().view());
  double previous = at_identity;
  for (double shift : {0.5, 1.0, 2.0, 3.0}) {
    const Image<float> moved = shifted(fixture_drr(), shift, 0.6 * shift);
    const double score = s->score(moved.view());
    EXPECT_LT(score, previous) << GetParam() << " at a shift of " << shift << " px";
    previous = score;
  }
}

TEST_P(EverySimilarity, CloneScoresTheSame) {
  auto s = make();
  ASSERT_TRUE(s->prepare(fixture_drr().view(), {}).ok());
  const Image<float> moved = shifted(fixture_drr(), 1.3, -0.7);
  auto copy = s->clone();
  EXPECT_DOUBLE_EQ(s->score(moved.view()), copy->score(moved.view()));
}

TEST_P(EverySimilarity, ExtremesGiveFiniteDefinedValues) {
  auto s = make();
  const Image<float>& f = fixture_drr();
  ASSERT_TRUE(s->prepare(f.view(), {}).ok());
  const Image<float> constant(f.rows(), f.cols(), 2.5f), zero(f.rows(), f.cols(), 0.f);
  Image<float> huge = f, with_nan = f;
  for (float& v : huge.pixels()) v *= 1e30f;
  with_nan.at(3, 4) = std::numeric_limits<float>::quiet_NaN();
  for (const Image<float>* im : std::vector<const Image<float>*>{&constant, &zero, &huge, &with_nan}) {
    const double v = s->score(im->view());
    EXPECT_TRUE(std::isfinite(v)) << GetParam();
  }
  // An empty mask leaves nothing to compare: the worst score.
  const Image<unsigned char> none(f.rows(), f.cols(), 0);
  EXPECT_EQ(s->score(f.view(), none.view()), s->worst_score());
  // A wrongly sized moving image as well.
  const Image<float> small(4, 4, 1.f);
  EXPECT_EQ(s->score(small.view()), s->worst_score());
  // A constant or all-zero fixed image prepares and scores finitely.
  ASSERT_TRUE(s->prepare(zero.view(), {}).ok());
  EXPECT_TRUE(std::isfinite(s->score(f.view())));
  EXPECT_FALSE(s->prepare(ImageView<const float>{}, {}).ok());
  const Image<unsigned char> wrong_mask(3, 3, 1);
  EXPECT_FALSE(s->prepare(f.view(), wrong_mask.view()).ok());
}

TEST_P(EverySimilarity, MaskedPixelsAreIgnored) {
  auto s = make();
  const Image<float>& f = fixture_drr();
  Image<unsigned char> mask(f.rows(), f.cols(), 1);
  Image<float> damaged = f;
  for (int r = 0; r < 10; ++r)
    for (int c = 0; c < 10; ++c) {
      mask.at(r, c) = 0;
      damaged.at(r, c) = 1e6f;
    }
  ASSERT_TRUE(s->prepare(f.view(), mask.view()).ok());
  Image<float> reference = f;
  for (int r = 0; r < 10; ++r)
    for (int c = 0; c < 10; ++c) reference.at(r, c) = -5.f;
  EXPECT_NEAR(s->score(damaged.view()), s->score(reference.view()), 1e-9);
}

INSTANTIATE_TEST_SUITE_P(Similarity, EverySimilarity, ::testing::ValuesIn(similarity_names()),
                         [](const ::testing::TestParamInfo<std::string>& p) { return p.param; });

TEST(Similarity, UnknownNameIsRefusedWithTheKnownOnes) {
  auto s = make_similarity("nope");
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("mi, nmi"), std::string::npos);
}

TEST(Similarity, NccAndGcIgnoreALinearIntensityMap) {
  for (const char* name : {"ncc", "rncc", "gc"}) {
    auto s = std::move(make_similarity(name)).value();
    ASSERT_TRUE(s->prepare(fixture_drr().view(), {}).ok());
    Image<float> mapped = fixture_drr();
    for (float& v : mapped.pixels()) v = 3.f * v + 7.f;
    EXPECT_NEAR(s->score(mapped.view()), 1.0, 1e-6) << name;
  }
}

// The fixture with a bright block (`rows` x `cols` px, top left at row r0, column c0) added: an
// organ that is somewhere else in the frame than in the planning CT.
Image<float> with_block(const Image<float>& in, int r0, int c0, int rows, int cols, float amplitude) {
  Image<float> out = in;
  for (int r = r0; r < r0 + rows; ++r)
    for (int c = c0; c < c0 + cols; ++c)
      if (r >= 0 && c >= 0 && r < out.rows() && c < out.cols()) out.at(r, c) += amplitude;
  return out;
}

// The shift along x (0.1 px steps within +-3 px) at which `name` scores the frame highest, where
// the frame is the fixture with a block at column 30 and noise of 2 % of its range, and the DRR at
// shift dx is the shifted fixture with the block at column 24 + dx (the block moved 6 px since the
// CT; the rest did not).
double best_shift_with_a_moved_block(const char* name) {
  const Image<float>& f = fixture_drr();
  float lo = f.at(0, 0), hi = lo;
  for (float v : f.pixels()) lo = std::min(lo, v), hi = std::max(hi, v);
  const float amplitude = 0.5f * (hi - lo);
  auto s = std::move(make_similarity(name)).value();
  Image<float> frame = with_block(f, 6, 30, 8, 8, amplitude);
  std::uint32_t state = 12345;  // a fixed linear congruential sequence: the same noise every run
  for (float& v : frame.pixels()) {
    state = state * 1664525u + 1013904223u;
    v += 0.02f * (hi - lo) * (static_cast<float>(state >> 8) / 16777216.f - 0.5f);
  }
  EXPECT_TRUE(s->prepare(frame.view(), {}).ok());
  double best = -1e300, best_dx = 0;
  for (int i = -30; i <= 30; ++i) {
    const double dx = 0.1 * i;
    const Image<float> drr = shifted(with_block(f, 6, 24, 8, 8, amplitude), dx, 0);
    const double score = s->score(drr.view());
    if (score > best) best = score, best_dx = dx;
  }
  return best_dx;
}

TEST(Similarity, RobustNccIsNotPulledByAStructureThatMovedWhereNccIs) {
  const double ncc = best_shift_with_a_moved_block("ncc");
  const double rncc = best_shift_with_a_moved_block("rncc");
  EXPECT_GE(std::abs(ncc), 0.5) << "the fixture no longer pulls plain NCC; the test shows nothing";
  EXPECT_LE(std::abs(rncc), 0.15) << "plain NCC's optimum: " << ncc << " px";
}

TEST(Similarity, RobustNccWithAFarCutOffIsNcc) {
  SimilarityOptions far;
  far.tukey_c = 100;
  auto rncc = std::move(make_similarity("rncc", far)).value();
  auto ncc = std::move(make_similarity("ncc")).value();
  ASSERT_TRUE(rncc->prepare(fixture_drr().view(), {}).ok());
  ASSERT_TRUE(ncc->prepare(fixture_drr().view(), {}).ok());
  for (double shift : {0.3, 1.0, 2.5}) {
    const Image<float> moved = shifted(fixture_drr(), shift, -0.4 * shift);
    const double plain = ncc->score(moved.view());
    EXPECT_LT(plain, 0.999) << "no residual to weigh at a shift of " << shift << " px";
    EXPECT_NEAR(rncc->score(moved.view()), plain, 2e-3 * (1 - plain)) << shift;
  }
}

TEST(Similarity, RobustNccCutOffOutsideItsRangeIsRefused) {
  for (double c : {0.0, 0.5, -1.0, 101.0, std::numeric_limits<double>::quiet_NaN(),
                   std::numeric_limits<double>::infinity()}) {
    SimilarityOptions options;
    options.tukey_c = c;
    EXPECT_FALSE(make_similarity("rncc", options).ok()) << c;
  }
  for (double c : {1.0, 100.0}) {
    SimilarityOptions options;
    options.tukey_c = c;
    EXPECT_TRUE(make_similarity("rncc", options).ok()) << c;
  }
}

TEST(Similarity, MutualInformationOfAnImageWithItselfIsItsEntropy) {
  // Two-level image, half and half: H = ln 2.
  Image<float> two(16, 16, 0.f);
  for (int r = 0; r < 16; ++r)
    for (int c = 8; c < 16; ++c) two.at(r, c) = 1.f;
  auto mi = std::move(make_similarity("mi")).value();
  ASSERT_TRUE(mi->prepare(two.view(), {}).ok());
  EXPECT_NEAR(mi->score(two.view()), std::log(2.0), 1e-9);
  auto nmi = std::move(make_similarity("nmi")).value();
  ASSERT_TRUE(nmi->prepare(two.view(), {}).ok());
  EXPECT_NEAR(nmi->score(two.view()), 2.0, 1e-9);
}

}  // namespace
}  // namespace lftrack::tracking

long lftrack_test_allocations();  // tests/tracking/drr_renderer_test.cpp

namespace lftrack::tracking {
namespace {

TEST_P(EverySimilarity, ScoringAllocatesNothing) {
  auto s = make();
  ASSERT_TRUE(s->prepare(fixture_drr().view(), {}).ok());
  const Image<float> moved = shifted(fixture_drr(), 0.8, 0.3);
  const Image<unsigned char> mask(moved.rows(), moved.cols(), 1);
  s->score(moved.view(), mask.view());
  const long before = lftrack_test_allocations();
  for (int i = 0; i < 5; ++i) s->score(moved.view(), mask.view());
  EXPECT_EQ(lftrack_test_allocations() - before, 0) << GetParam();
}

}  // namespace
}  // namespace lftrack::tracking
