// The (s, t)-averaged copies of a light field (LightField::downsampled_st) and the renderer's
// use of them for coarse pixels.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "fixtures.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/light_field.hpp"

namespace lftrack::tracking {
namespace {

using test::fixture_light_field;
using test::fixture_plan;

// The trapezoid mean the copy's sample (iu, iv, js, jt) should hold, from the source's samples.
double expected_average(const LightField& f, int factor, int iu, int iv, int js, int jt) {
  const auto& size = f.geometry().size;
  double sum = 0;
  for (int ks = -factor / 2; ks <= factor / 2; ++ks)
    for (int kt = -factor / 2; kt <= factor / 2; ++kt) {
      const double ws = (std::abs(ks) == factor / 2 ? 0.5 : 1.0) / factor;
      const double wt = (std::abs(kt) == factor / 2 ? 0.5 : 1.0) / factor;
      const int is = std::clamp(js * factor + ks, 0, size[2] - 1), it = std::clamp(jt * factor + kt, 0, size[3] - 1);
      sum += ws * wt * f.sample(iu, iv, is, it);
    }
  return sum;
}

TEST(LightFieldAveraged, SamplesAreTrapezoidMeansOnACoarserGridOverTheSameStart) {
  for (LightFieldStorage storage : {LightFieldStorage::kFloat32, LightFieldStorage::kFixed16, LightFieldStorage::kVq}) {
    const auto source = fixture_light_field(storage);
    const LightFieldGeometry& g = source->geometry();
    for (int factor : {2, 4}) {
      SCOPED_TRACE(to_string(storage) + std::string(", factor ") + std::to_string(factor));
      auto averaged = LightField::downsampled_st(*source, factor, nullptr);
      ASSERT_TRUE(averaged.ok()) << averaged.status().message();
      const LightFieldGeometry& m = (*averaged)->geometry();
      EXPECT_EQ((*averaged)->header().storage, LightFieldStorage::kFloat32);
      for (int a = 0; a < 2; ++a) {  // (u, v) untouched
        EXPECT_EQ(m.size[a], g.size[a]);
        EXPECT_EQ(m.lo[a], g.lo[a]);
        EXPECT_EQ(m.hi[a], g.hi[a]);
      }
      for (int a = 2; a < 4; ++a) {
        EXPECT_EQ(m.size[a], (g.size[a] - 2 + factor) / factor + 1);
        EXPECT_EQ(m.lo[a], g.lo[a]);
        EXPECT_NEAR(m.spacing(a), factor * g.spacing(a), 1e-9);
        EXPECT_GE(m.hi[a], g.hi[a] - 1e-9) << "reaches the source's last sample";
        EXPECT_LT(m.hi[a], g.hi[a] + factor * g.spacing(a));
      }
      EXPECT_EQ((*averaged)->header().plan_hash, 0u) << "never taken for the field its plan describes";
      std::mt19937 rng(7);
      for (int k = 0; k < 300; ++k) {
        const int iu = int(rng() % unsigned(m.size[0])), iv = int(rng() % unsigned(m.size[1]));
        // Edges (replicated samples) and interior alike.
        const int js = k % 3 == 0 ? 0 : int(rng() % unsigned(m.size[2]));
        const int jt = k % 5 == 0 ? m.size[3] - 1 : int(rng() % unsigned(m.size[3]));
        const double expected = expected_average(*source, factor, iu, iv, js, jt);
        EXPECT_NEAR((*averaged)->sample(iu, iv, js, jt), expected, 1e-5 * (1 + std::abs(expected)));
      }
    }
  }
}

TEST(LightFieldAveraged, RefusesFactorsThatAreNotPowersOfTwoAndFieldsTooSmallForThem) {
  const auto source = fixture_light_field(LightFieldStorage::kFloat32);  // 64 x 64 (s, t)
  for (int factor : {-2, 0, 1, 3, 6, 128})
    EXPECT_FALSE(LightField::downsampled_st(*source, factor, nullptr).ok()) << factor;
  EXPECT_FALSE(LightField::downsampled_st(*source, 64, nullptr).ok()) << "fewer than 64 steps to average";
  EXPECT_TRUE(LightField::downsampled_st(*source, 32, nullptr).ok()) << "63 steps: three samples per axis";
}

// A coarse view of the fixture: its detector binned 4 x 4, as the registration's coarse levels
// see it.
XrayView coarse_view(const XrayView& fine, int bin) {
  return fine.resampled(0, 0, fine.rows / bin * bin, fine.cols / bin * bin, fine.rows / bin, fine.cols / bin);
}

Image<float> render(const DrrRenderer& r, const Pose& T, const XrayView& view) {
  Image<float> out(view.rows, view.cols);
  EXPECT_TRUE(r.render(T, view, PixelWindow::full(view.rows, view.cols), out.view()).ok());
  return out;
}

TEST(LightFieldAveraged, CoarsePixelsRenderTheMeanOverTheirFootprintAndFinePixelsAreUnchanged) {
  const auto field = fixture_light_field(LightFieldStorage::kFloat32);
  RendererOptions with, without, exact_options;
  with.light_fields = without.light_fields = {field};
  without.light_field_mips = false;
  auto averaging = make_renderer("lightfield", nullptr, with);
  auto sampling = make_renderer("lightfield", nullptr, without);
  auto exact = make_renderer("siddon", test::fixture_volume(), exact_options);
  ASSERT_TRUE(averaging.ok() && sampling.ok() && exact.ok());
  EXPECT_GT((*averaging)->bytes(), (*sampling)->bytes()) << "the copies' memory is counted";

  const XrayView fine = fixture_plan().view_room;
  PoseDelta d;
  d.translation_mm = Eigen::Vector3d(1.0, -0.5, 0.7);
  d.rotation_rad = Eigen::Vector3d(0.02, -0.01, 0.015);
  const Pose T = apply_delta(Pose::Identity(), d, Eigen::Vector3d::Zero());

  // Fine pixels span under two (s, t) samples: the same image, bit for bit, with or without copies.
  const Image<float> a = render(**averaging, T, fine), b = render(**sampling, T, fine);
  EXPECT_EQ(a.pixels(), b.pixels());

  // Coarse pixels: compared with the mean of the fine exact DRR over each pixel's block (what a
  // binned detector pixel measures), the averaged copy is closer than the ray through the centre.
  const int bin = 4;
  const XrayView coarse = coarse_view(fine, bin);
  const Image<float> truth_fine = render(**exact, T, fine);
  const Image<float> mean_copy = render(**averaging, T, coarse), centre_ray = render(**sampling, T, coarse);
  double error_copy = 0, error_centre = 0, signal = 0;
  for (int r = 0; r < coarse.rows; ++r)
    for (int c = 0; c < coarse.cols; ++c) {
      double block = 0;
      for (int i = 0; i < bin; ++i)
        for (int j = 0; j < bin; ++j) block += truth_fine.at(r * bin + i, c * bin + j);
      block /= bin * bin;
      error_copy += std::pow(mean_copy.at(r, c) - block, 2);
      error_centre += std::pow(centre_ray.at(r, c) - block, 2);
      signal += block * block;
    }
  EXPECT_LT(error_copy, 0.8 * error_centre) << "rms " << std::sqrt(error_copy / signal) << " against "
                                            << std::sqrt(error_centre / signal) << " of the signal";
  EXPECT_LT(std::sqrt(error_copy / signal), 0.05);
}

// At the field's edge (the envelope's corner pose) a coarse view masks exactly the pixels the
// field alone masks, whichever copy it reads: the copies end where the field ends.
TEST(LightFieldAveraged, CoarseViewsMaskWhatTheFieldAloneMasks) {
  for (LightFieldStorage storage : {LightFieldStorage::kFloat32, LightFieldStorage::kFixed16}) {
    const auto field = fixture_light_field(storage);
    RendererOptions with, without;
    with.light_fields = without.light_fields = {field};
    without.light_field_mips = false;
    auto averaging = make_renderer("lightfield", nullptr, with);
    auto sampling = make_renderer("lightfield", nullptr, without);
    ASSERT_TRUE(averaging.ok() && sampling.ok());
    const XrayView fine = fixture_plan().view_room;
    for (int bin : {2, 3, 4, 6}) {  // footprints of about 2 to 6 samples: both copies
      const XrayView coarse = coarse_view(fine, bin);
      for (double reach : {0.9, 1.3, 2.0}) {  // inside, at and beyond the envelope's corner
        SCOPED_TRACE(to_string(storage) + std::string(", bin ") + std::to_string(bin) + ", reach " +
                     std::to_string(reach));
        PoseDelta d;
        d.translation_mm = reach * Eigen::Vector3d(3, -3, 3);
        d.rotation_rad = reach * 0.2 * Eigen::Vector3d(1, -1, 1);
        const Pose T = apply_delta(Pose::Identity(), d, Eigen::Vector3d::Zero());
        Image<float> a(coarse.rows, coarse.cols), b(coarse.rows, coarse.cols);
        Image<unsigned char> va(coarse.rows, coarse.cols), vb(coarse.rows, coarse.cols);
        RenderExtras ea, eb;
        ea.valid = va.view();
        eb.valid = vb.view();
        const PixelWindow w = PixelWindow::full(coarse.rows, coarse.cols);
        ASSERT_TRUE((*averaging)->render(T, coarse, w, a.view(), &ea).ok());
        ASSERT_TRUE((*sampling)->render(T, coarse, w, b.view(), &eb).ok());
        EXPECT_EQ(va.pixels(), vb.pixels());
        EXPECT_EQ(ea.masked_pixels, eb.masked_pixels);
        for (float v : a.pixels()) ASSERT_TRUE(std::isfinite(v));
      }
    }
  }
}

}  // namespace
}  // namespace lftrack::tracking
