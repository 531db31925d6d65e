#include <gtest/gtest.h>

#include <random>

#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

XrayView oblique_view() {
  return *XrayView::isocentric("A", Vector3d(3, -2, 5), Vector3d(1, -1, 0.2), Vector3d(0, 0, 1), 1500, 2100,
                               512, 400, 0.4);
}

TEST(XrayView, IsocentricGeometry) {
  const XrayView v = oblique_view();
  EXPECT_TRUE(v.validate().ok());
  EXPECT_NEAR(v.source_to_detector_mm(), 2100, 1e-9);
  EXPECT_NEAR((v.source_mm - Vector3d(3, -2, 5)).norm(), 1500, 1e-9);
  // The detector centre is on the beam axis through the isocentre.
  const Vector3d centre = v.pixel_centre_mm(255.5, 199.5);
  EXPECT_LT((centre - v.principal_point_mm()).norm(), 1e-9);
  const Vector3d axis = (Vector3d(3, -2, 5) - v.source_mm).normalized();
  EXPECT_LT(((centre - v.source_mm).normalized() - axis).norm(), 1e-12);
  // Row 0 is the top: towards 'up'.
  EXPECT_GT(v.pixel_centre_mm(0, 200).z(), v.pixel_centre_mm(511, 200).z());
}

TEST(XrayView, ProjectionMatrixMapsPointsOnAPixelRayToThatPixel) {
  const XrayView v = oblique_view();
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(0, 1);
  for (int n = 0; n < 100; ++n) {
    const double row = 511 * u(rng), col = 399 * u(rng);
    const Vector3d on_ray = v.source_mm + (0.2 + 0.7 * u(rng)) * (v.pixel_centre_mm(row, col) - v.source_mm);
    const auto px = v.project(on_ray);
    ASSERT_TRUE(px.has_value());
    EXPECT_NEAR(px->x(), col, 1e-7);
    EXPECT_NEAR(px->y(), row, 1e-7);
  }
  // Behind the source: no projection.
  EXPECT_FALSE(v.project(v.source_mm + (v.source_mm - v.principal_point_mm())).has_value());
}

TEST(XrayView, TransformedViewProjectsTransformedPointsAlike) {
  const XrayView v = oblique_view();
  Pose T = Pose::Identity();
  T.linear() = rotation_exp(Vector3d(0.3, 0.1, -0.4));
  T.translation() = Vector3d(-40, 25, 11);
  const XrayView w = v.transformed(T);
  const Vector3d p(10, 20, -15);
  EXPECT_TRUE(v.project(p)->isApprox(*w.project(T * p), 1e-9));
}

TEST(XrayView, ResampledWindowCoversTheSameArea) {
  const XrayView v = oblique_view();
  const XrayView r = v.resampled(100, 50, 200, 120, 100, 40);  // 2x binning in rows, 3x in cols
  EXPECT_NEAR(r.pitch_row_mm, 0.8, 1e-12);
  EXPECT_NEAR(r.pitch_col_mm, 1.2, 1e-12);
  // The outer corners of the window coincide.
  EXPECT_LT((r.pixel_centre_mm(-0.5, -0.5) - v.pixel_centre_mm(99.5, 49.5)).norm(), 1e-9);
  EXPECT_LT((r.pixel_centre_mm(99.5, 39.5) - v.pixel_centre_mm(299.5, 169.5)).norm(), 1e-9);
}

TEST(XrayView, ValidateRejectsBadGeometry) {
  const XrayView good = oblique_view();
  {
    XrayView v = good;
    v.rows = 0;
    EXPECT_FALSE(v.validate().ok());
  }
  {
    XrayView v = good;
    v.pitch_row_mm = 0;
    EXPECT_FALSE(v.validate().ok());
  }
  {
    XrayView v = good;
    v.col_axis = v.row_axis;
    EXPECT_FALSE(v.validate().ok());
  }
  {
    XrayView v = good;
    v.source_mm.x() = std::nan("");
    EXPECT_FALSE(v.validate().ok());
  }
  {
    XrayView v = good;
    v.source_mm = v.pixel00_mm;
    EXPECT_FALSE(v.validate().ok());
  }
  EXPECT_FALSE(
      XrayView::isocentric("x", Vector3d::Zero(), Vector3d(0, 0, 1), Vector3d(0, 0, 1), 1000, 1500, 10, 10, 1)
          .ok());
  EXPECT_FALSE(
      XrayView::isocentric("x", Vector3d::Zero(), Vector3d(1, 0, 0), Vector3d(0, 0, 1), 1500, 1000, 10, 10, 1)
          .ok());
}

}  // namespace
}  // namespace lftrack::tracking

namespace lftrack::tracking {
namespace {

TEST(XrayView, DetectorCentreAndAxes) {
  auto v =
      XrayView::isocentric("A", Eigen::Vector3d(1, 2, 3), {0, -1, 0}, {0, 0, 1}, 1000, 1500, 300, 200, 0.5);
  ASSERT_TRUE(v.ok());
  // An isocentric detector is centred on the beam through the isocentre.
  EXPECT_LT((v->detector_centre_mm() - Eigen::Vector3d(1, 2 + 500, 3)).norm(), 1e-9);
  const Eigen::Matrix3d axes = v->detector_axes();
  EXPECT_TRUE((axes.transpose() * axes).isIdentity(1e-12));
  EXPECT_GT(axes.determinant(), 0);
  EXPECT_TRUE(axes.col(2).isApprox(Eigen::Vector3d(0, 1, 0), 1e-12)) << "col x row points along the beam";
  XrayView moved = *v;
  moved.set_detector_centre(Eigen::Vector3d(4, 500, -2));
  EXPECT_LT((moved.detector_centre_mm() - Eigen::Vector3d(4, 500, -2)).norm(), 1e-9);
  EXPECT_EQ(moved.col_axis, v->col_axis);
}

}  // namespace
}  // namespace lftrack::tracking
