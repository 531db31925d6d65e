// Light-field rendering: at and beyond the envelope, the vectorised kernels against the portable
// ones, and the source image against the per-ray blend.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <utility>

#include "fixtures.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;
using test::fixture_light_field;
using test::fixture_plan;

// Poses at the envelope's edge render fully; beyond it rays leave the field: they are masked and
// counted, set to 0, and the pose is reported as outside the envelope.
TEST(LightFieldRender, EnvelopeEdgeAndBeyond) {
  const auto field = fixture_light_field(LightFieldStorage::kFloat32);
  RendererOptions options;
  options.light_fields = {field};
  auto renderer = make_renderer("lightfield", nullptr, options);
  ASSERT_TRUE(renderer.ok()) << renderer.status().message();
  const LightFieldPlanInput in = fixture_plan();
  const XrayView view = in.view_room;
  Image<float> out(view.rows, view.cols);
  Image<unsigned char> valid(view.rows, view.cols);
  RenderExtras extras;
  extras.valid = valid.view();

  PoseDelta edge;
  edge.translation_mm = Vector3d(3, -3, 3);
  edge.rotation_rad = deg_to_rad(12.0) * Vector3d(1, -1, 1);
  ASSERT_TRUE((*renderer)
                  ->render(apply_delta(Pose::Identity(), edge, Vector3d::Zero()), view,
                           PixelWindow::full(view.rows, view.cols), out.view(), &extras)
                  .ok());
  EXPECT_EQ(extras.masked_pixels, 0);
  EXPECT_FALSE(extras.pose_outside_envelope);

  PoseDelta beyond;
  beyond.translation_mm = Vector3d(0, 0, 40);
  beyond.rotation_rad = deg_to_rad(30.0) * Vector3d(1, 0, 0);
  ASSERT_TRUE((*renderer)
                  ->render(apply_delta(Pose::Identity(), beyond, Vector3d::Zero()), view,
                           PixelWindow::full(view.rows, view.cols), out.view(), &extras)
                  .ok());
  EXPECT_TRUE(extras.pose_outside_envelope);
  EXPECT_GT(extras.masked_pixels, 0);
  int zeros = 0;
  for (std::size_t i = 0; i < out.pixels().size(); ++i) {
    ASSERT_TRUE(std::isfinite(out.pixels()[i]));
    if (valid.pixels()[i] == 0) {
      EXPECT_EQ(out.pixels()[i], 0.0f);
      ++zeros;
    }
  }
  EXPECT_EQ(zeros, extras.masked_pixels);
}

// The vectorised kernels (AVX-512 and AVX2, where the CPU has them) against the portable scalar
// kernels, with a window whose width is a multiple of neither 8 nor 16, and poses inside the
// field (where the AVX-512 and AVX2 kernels read runs of samples), at its edge and outside it;
// the whole detector, its 2 x 2 binning (wider runs per chunk) and a 256 x 256 image of it.
struct KernelCase {
  LightFieldStorage storage;
  SimdLevel simd;
  bool source_image = false;  // both renderers blend (u, v) once per (s, t) sample
  int threads = 1;             // the vectorised renderer's pool: its blend and rows in bands
};
class VectorisedKernel : public ::testing::TestWithParam<KernelCase> {};

// Two renderers' images of one pose, the window's size: values, masks and masked counts.
struct TwoRenders {
  Image<float> a, b;
  Image<unsigned char> valid_a, valid_b;
  int masked_a = -1, masked_b = -1;
};
TwoRenders render_both(DrrRenderer& first, DrrRenderer& second, const Pose& pose, const XrayView& view,
                       const PixelWindow& w) {
  TwoRenders t{Image<float>(w.rows, w.cols), Image<float>(w.rows, w.cols), Image<unsigned char>(w.rows, w.cols),
               Image<unsigned char>(w.rows, w.cols)};
  RenderExtras ea, eb;
  ea.valid = t.valid_a.view();
  eb.valid = t.valid_b.view();
  if (first.render(pose, view, w, t.a.view(), &ea).ok()) t.masked_a = ea.masked_pixels;
  if (second.render(pose, view, w, t.b.view(), &eb).ok()) t.masked_b = eb.masked_pixels;
  return t;
}

TEST_P(VectorisedKernel, MatchesScalar) {
  RendererOptions scalar_options, simd_options;
  scalar_options.light_fields = simd_options.light_fields = {fixture_light_field(GetParam().storage)};
  scalar_options.simd = SimdLevel::kScalar;
  simd_options.simd = GetParam().simd;
  scalar_options.light_field_source_image = simd_options.light_field_source_image = GetParam().source_image;
  ThreadPool pool(GetParam().threads);
  if (GetParam().threads > 1) simd_options.pool = &pool;
  auto scalar = make_renderer("lightfield", nullptr, scalar_options);
  auto simd = make_renderer("lightfield", nullptr, simd_options);
  ASSERT_TRUE(scalar.ok() && simd.ok());
  const XrayView detector = fixture_plan().view_room;
  const XrayView binned = detector.resampled(0, 0, detector.rows, detector.cols, detector.rows / 2, detector.cols / 2);
  // A 256 x 256 image of the detector, as the benchmark renders: pixels finer than the field's
  // samples, where the AVX2 source-image kernel takes most chunks as one run over one image row.
  const XrayView fine = detector.resampled(0, 0, detector.rows, detector.cols, 256, 256);
  for (const auto& [view, w] : {std::pair{detector, PixelWindow{3, 2, 41, 37}},
                                std::pair{detector, PixelWindow::full(detector.rows, detector.cols)},
                                std::pair{binned, PixelWindow::full(binned.rows, binned.cols)},
                                std::pair{fine, PixelWindow::full(fine.rows, fine.cols)}}) {
    for (double shift : {0.0, 2.0, 30.0}) {
      for (double turn : {0.0, 1.0}) {
        Pose pose = Pose::Identity();
        pose.linear() = rotation_exp(turn * Vector3d(0.05, -0.08, 0.1));
        pose.translation() = Vector3d(shift, -turn, 0.5 * turn);
        const TwoRenders t = render_both(**scalar, **simd, pose, view, w);
        ASSERT_GE(t.masked_a, 0);
        EXPECT_EQ(t.masked_a, t.masked_b) << shift << " " << turn;
        EXPECT_EQ(t.valid_a.pixels(), t.valid_b.pixels()) << shift << " " << turn;
        for (std::size_t i = 0; i < t.a.pixels().size(); ++i) {
          ASSERT_NEAR(t.a.pixels()[i], t.b.pixels()[i], 1e-4f * (1 + t.a.pixels()[i]))
              << shift << " " << turn << " " << i;
        }
      }
    }
  }
}

// The fixture's float field rendered by the portable kernel and by the best vectorised one the
// CPU has, both through the source image or both per ray.
std::pair<Result<std::unique_ptr<DrrRenderer>>, Result<std::unique_ptr<DrrRenderer>>> portable_and_best(
    bool source_image) {
  RendererOptions options;
  options.light_fields = {fixture_light_field(LightFieldStorage::kFloat32)};
  options.light_field_source_image = source_image;
  options.simd = SimdLevel::kScalar;
  auto portable = make_renderer("lightfield", nullptr, options);
  options.simd = SimdLevel::kBest;
  return {std::move(portable), make_renderer("lightfield", nullptr, options)};
}

// The AVX2 kernels skip the per-pixel field test on rows whose two end rays lie inside the field
// with a margin (row_inside_field). Rows that graze the field's edge must keep the per-pixel
// mask: the whole detector shifted and turned in small steps, so that the edge crosses rows and
// columns at many sub-sample positions, against the portable kernel (which tests every pixel).
TEST(VectorisedKernelRows, RowsGrazingTheFieldsEdgeKeepThePerPixelMask) {
  const XrayView detector = fixture_plan().view_room;
  const PixelWindow w = PixelWindow::full(detector.rows, detector.cols);
  for (const bool source_image : {false, true}) {
    auto [scalar, simd] = portable_and_best(source_image);
    ASSERT_TRUE(scalar.ok() && simd.ok());
    int partly_masked = 0;
    for (int step = 0; step < 40; ++step) {
      Pose pose = Pose::Identity();
      pose.linear() = rotation_exp(Vector3d(0.0013, -0.0021, 0.0017) * step);
      pose.translation() = Vector3d(1.07, -0.83, 0.61) * step;
      const TwoRenders t = render_both(**scalar, **simd, pose, detector, w);
      ASSERT_GE(t.masked_a, 0);
      ASSERT_EQ(t.masked_a, t.masked_b) << step << " " << source_image;
      ASSERT_EQ(t.valid_a.pixels(), t.valid_b.pixels()) << step << " " << source_image;
      partly_masked += t.masked_a > 0 && t.masked_a < w.rows * w.cols;
    }
    EXPECT_GT(partly_masked, 10) << "the edge must cross the detector in most steps";
  }
}

// The AVX2 source-image kernel reads a chunk of eight pixels as a run over one image row where
// it can, and through the general path where its pixels straddle two or three rows. A turn about
// the view's axis tilts the pixel rows across the image's rows, so that from none to nearly all
// chunks straddle. Swept in quarter-degree steps to 12 degrees each way, on a 256 x 256 image
// finer than the field's samples: the same mask and, within float rounding, the portable
// kernel's values. (A one-row run let through with a lane in the next row, or a two-row run
// blended with its lanes' rows swapped, is off by a sample's difference, far more than rounding.)
TEST(VectorisedKernelRows, EveryTiltAcrossTheImageRowsMatchesThePortableKernel) {
  const XrayView detector = fixture_plan().view_room;
  const XrayView fine = detector.resampled(0, 0, detector.rows, detector.cols, 256, 256);
  const PixelWindow w = PixelWindow::full(fine.rows, fine.cols);
  auto [scalar, simd] = portable_and_best(true);
  ASSERT_TRUE(scalar.ok() && simd.ok());
  const Vector3d view_axis = fine.source_mm.normalized();  // the isocentre is the room origin
  double largest_difference = 0;
  for (int step = -48; step <= 48; ++step) {
    Pose pose = Pose::Identity();
    pose.linear() = rotation_exp(deg_to_rad(0.25 * step) * view_axis);
    pose.translation() = Vector3d(0.37, -0.21, 0.13);
    const TwoRenders t = render_both(**scalar, **simd, pose, fine, w);
    ASSERT_EQ(t.masked_a, 0) << step;
    ASSERT_EQ(t.masked_b, 0) << step;
    for (std::size_t i = 0; i < t.a.pixels().size(); ++i) {
      const double difference = std::abs(double(t.a.pixels()[i]) - double(t.b.pixels()[i]));
      largest_difference = std::max(largest_difference, difference / (1 + double(t.a.pixels()[i])));
      ASSERT_LE(difference, 1e-5 * (1 + double(t.a.pixels()[i]))) << "turn " << 0.25 * step << " deg, pixel " << i;
    }
  }
  RecordProperty("largest_relative_difference", std::to_string(largest_difference));
}

INSTANTIATE_TEST_SUITE_P(StorageModes, VectorisedKernel,
                         ::testing::Values(KernelCase{LightFieldStorage::kFloat32, SimdLevel::kBest},
                                           KernelCase{LightFieldStorage::kFixed16, SimdLevel::kBest},
                                           KernelCase{LightFieldStorage::kVq, SimdLevel::kBest},
                                           KernelCase{LightFieldStorage::kFloat32, SimdLevel::kAvx2},
                                           KernelCase{LightFieldStorage::kFixed16, SimdLevel::kAvx2},
                                           KernelCase{LightFieldStorage::kFloat32, SimdLevel::kAvx2Gathers},
                                           KernelCase{LightFieldStorage::kFixed16, SimdLevel::kAvx2Gathers},
                                           KernelCase{LightFieldStorage::kFloat32, SimdLevel::kBest, true},
                                           KernelCase{LightFieldStorage::kFixed16, SimdLevel::kBest, true},
                                           KernelCase{LightFieldStorage::kFloat32, SimdLevel::kBest, true, 3},
                                           KernelCase{LightFieldStorage::kFixed16, SimdLevel::kBest, true, 3}),
                         [](const auto& p) {
                           const char* simd = p.param.simd == SimdLevel::kBest   ? "_best"
                                              : p.param.simd == SimdLevel::kAvx2 ? "_avx2"
                                                                                 : "_avx2_gathers";
                           return std::string(to_string(p.param.storage)) + simd +
                                  (p.param.source_image ? "_source_image" : "") +
                                  (p.param.threads > 1 ? "_pooled" : "");
                         });

// Two portable renderers of the fixture's field: the per-ray blend and the source image.
std::pair<Result<std::unique_ptr<DrrRenderer>>, Result<std::unique_ptr<DrrRenderer>>> per_ray_and_source_image(
    LightFieldStorage storage) {
  RendererOptions options;
  options.light_fields = {fixture_light_field(storage)};
  options.simd = SimdLevel::kScalar;
  options.light_field_source_image = false;
  auto per_ray = make_renderer("lightfield", nullptr, options);
  options.light_field_source_image = true;
  return {std::move(per_ray), make_renderer("lightfield", nullptr, options)};
}

// The source image (RendererOptions::light_field_source_image) against the papers' per-ray
// quadrilinear blend, both portable: the same mask bit for bit, and values that differ only by
// how far (u, v) moves between a pixel's ray and its (s, t) neighbours' rays. At the nominal pose
// the source sits on the source plane, every ray has the same (u, v), and the two blends are the
// same sums in another order. Away from it the difference must stay small (6.4e-5 of the peak at
// worst here, at the envelope's edge; (u, v) held at one value for the whole window instead of
// following the rays gives up to 1e-2), yet not vanish (or the image path was not taken).
TEST(LightFieldRender, TheSourceImageIsThePerRayBlendUpToTheRaysUvDrift) {
  for (LightFieldStorage storage : {LightFieldStorage::kFloat32, LightFieldStorage::kFixed16}) {
    auto [per_ray, image] = per_ray_and_source_image(storage);
    ASSERT_TRUE(per_ray.ok() && image.ok());
    const XrayView view = fixture_plan().view_room;
    const XrayView binned = view.resampled(0, 0, view.rows, view.cols, view.rows / 2, view.cols / 2);
    struct Case {
      const XrayView* view;
      PixelWindow window;
      Vector3d translation_mm, rotation_deg;
    };
    const Case cases[] = {
        {&view, PixelWindow::full(view.rows, view.cols), Vector3d::Zero(), Vector3d::Zero()},
        {&view, PixelWindow{3, 2, 41, 37}, Vector3d::Zero(), Vector3d::Zero()},
        {&view, PixelWindow::full(view.rows, view.cols), Vector3d(3, -3, 3), Vector3d(12, -12, 12)},
        {&view, PixelWindow{5, 7, 30, 31}, Vector3d(-2, 1, 2.5), Vector3d(-4, 7, 2)},
        {&binned, PixelWindow::full(binned.rows, binned.cols), Vector3d(1, 2, -3), Vector3d(6, 0, -9)},
        // Partly outside the field: masked pixels are 0 in both.
        {&view, PixelWindow::full(view.rows, view.cols), Vector3d(0, 0, 40), Vector3d(30, 0, 0)},
    };
    for (const Case& c : cases) {
      PoseDelta d;
      d.translation_mm = c.translation_mm;
      d.rotation_rad = deg_to_rad(1.0) * c.rotation_deg;
      const Pose pose = apply_delta(Pose::Identity(), d, Vector3d::Zero());
      const PixelWindow& w = c.window;
      Image<float> a(w.rows, w.cols), b(w.rows, w.cols);
      Image<unsigned char> va(w.rows, w.cols), vb(w.rows, w.cols);
      RenderExtras ea, eb;
      ea.valid = va.view();
      eb.valid = vb.view();
      const Status sa = (*per_ray)->render(pose, *c.view, w, a.view(), &ea);
      const Status sb = (*image)->render(pose, *c.view, w, b.view(), &eb);
      ASSERT_TRUE(sa.ok() && sb.ok()) << sa.message() << " / " << sb.message();
      const std::string where = std::string(to_string(storage)) + " t " + std::to_string(c.translation_mm.x()) +
                                " r " + std::to_string(c.rotation_deg.x());
      EXPECT_EQ(ea.masked_pixels, eb.masked_pixels) << where;
      EXPECT_EQ(va.pixels(), vb.pixels()) << where;
      float peak = 0, worst = 0;
      for (std::size_t i = 0; i < a.pixels().size(); ++i) {
        ASSERT_TRUE(std::isfinite(b.pixels()[i])) << where;
        if (vb.pixels()[i] == 0) {
          ASSERT_EQ(b.pixels()[i], 0.0f) << where;
        }
        peak = std::max(peak, std::abs(a.pixels()[i]));
        worst = std::max(worst, std::abs(a.pixels()[i] - b.pixels()[i]));
      }
      ASSERT_GT(peak, 0.0f) << where;
      const bool nominal = c.translation_mm.isZero() && c.rotation_deg.isZero();
      EXPECT_LE(worst, (nominal ? 2e-6f : 3e-4f) * peak) << where;  // measured: 0 and 6.4e-5 at worst
      if (!nominal) {
        EXPECT_GT(worst, 0.0f) << where;
      }
    }
  }
}

// Rays that all miss the field (no (s, t) box holds them; the per-ray blend renders instead) are
// masked and 0 with the source image on, as with it off: the same pixels and mask, bit for bit.
TEST(LightFieldRender, RaysThatAllMissTheFieldAreMaskedAsByThePerRayBlend) {
  auto [per_ray, image] = per_ray_and_source_image(LightFieldStorage::kFloat32);
  ASSERT_TRUE(per_ray.ok() && image.ok());
  const XrayView view = fixture_plan().view_room;
  const PixelWindow w = PixelWindow::full(view.rows, view.cols);
  for (const Vector3d& shift : {Vector3d(1000, 0, 0), Vector3d(0, -1000, 0), Vector3d(0, 0, 1e6)}) {
    Pose pose = Pose::Identity();
    pose.translation() = shift;
    Image<float> a(w.rows, w.cols, 1.0f), b(w.rows, w.cols, 1.0f);
    Image<unsigned char> va(w.rows, w.cols), vb(w.rows, w.cols);
    RenderExtras ea, eb;
    ea.valid = va.view();
    eb.valid = vb.view();
    ASSERT_TRUE((*per_ray)->render(pose, view, w, a.view(), &ea).ok());
    ASSERT_TRUE((*image)->render(pose, view, w, b.view(), &eb).ok());
    EXPECT_EQ(eb.masked_pixels, w.rows * w.cols) << shift.transpose();
    EXPECT_EQ(ea.masked_pixels, eb.masked_pixels);
    EXPECT_EQ(va.pixels(), vb.pixels());
    EXPECT_EQ(a.pixels(), b.pixels());
  }
}

TEST(LightFieldRender, RefusesViewsItWasNotBuiltFor) {
  RendererOptions options;
  options.light_fields = {fixture_light_field(LightFieldStorage::kFloat32)};
  auto renderer = make_renderer("lightfield", nullptr, options);
  ASSERT_TRUE(renderer.ok());
  XrayView other = fixture_plan().view_room;
  Image<float> out(other.rows, other.cols);
  other.name = "B";
  EXPECT_EQ((*renderer)
                ->render(Pose::Identity(), other, PixelWindow::full(other.rows, other.cols), out.view())
                .code(),
            StatusCode::kNotFound);
  other.name = "A";
  other.source_mm.x() += 5;
  EXPECT_FALSE((*renderer)
                   ->render(Pose::Identity(), other, PixelWindow::full(other.rows, other.cols), out.view())
                   .ok());
}

}  // namespace
}  // namespace lftrack::tracking
