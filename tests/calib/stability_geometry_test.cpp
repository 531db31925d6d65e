// Numerical stability at the extremes: geometry (docs/stability.md, "Geometry"). Triangulation of
// parallel and near-parallel rays, rigid fits of colinear, coplanar and repeated fiducials, and a
// source on the detector plane: each a finite answer or a refusal that says why.

#include <gtest/gtest.h>

#include <cmath>

#include "lftrack/calib/triangulation.hpp"
#include "lftrack/tracking/pose.hpp"

namespace lftrack::calib {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;
using tracking::XrayView;

XrayView view_from(const Vector3d& direction) {
  return *XrayView::isocentric("V", Vector3d::Zero(), direction.normalized(), Vector3d(0, 0, 1), 1000, 1500,
                               256, 256, 0.5);
}

TEST(StabilityGeometry, ParallelRaysAreRefused) {
  const XrayView a = view_from(Vector3d(1, 0, 0));
  XrayView b = a;  // the same view: every pair of rays through one pixel is the same line
  auto r = triangulate(a, Vector2d(128, 128), b, Vector2d(128, 128));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("parallel"), std::string::npos) << r.status().message();
  // Two sources far apart along one line, looking the same way: parallel central rays.
  b.source_mm = a.source_mm * 2;
  b.pixel00_mm += a.source_mm;
  EXPECT_FALSE(triangulate(a, Vector2d(128, 128), b, Vector2d(128, 128)).ok());
}

TEST(StabilityGeometry, NearParallelRaysAreRefusedOrFinite) {
  const XrayView a = view_from(Vector3d(1, 0, 0));
  for (double deg : {1e-9, 1e-6, 1e-3, 0.1, 1.0}) {
    const double rad = tracking::deg_to_rad(deg);
    const XrayView b = view_from(Vector3d(std::cos(rad), std::sin(rad), 0));
    auto r = triangulate(a, Vector2d(127.5, 127.5), b, Vector2d(127.5, 127.5));
    if (r.ok()) {
      ASSERT_TRUE(r->point_mm.allFinite()) << deg;
      ASSERT_TRUE(std::isfinite(r->gap_mm)) << deg;
      EXPECT_LT(r->point_mm.norm(), 1.0) << deg << " degrees: the isocentre";
    } else {
      EXPECT_LT(deg, 1.0) << "views 1 degree apart still triangulate";
    }
  }
}

std::vector<Vector3d> moved(const std::vector<Vector3d>& points, const Eigen::Isometry3d& T) {
  std::vector<Vector3d> out;
  for (const auto& p : points) out.push_back(T * p);
  return out;
}

Eigen::Isometry3d some_motion() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = tracking::rotation_exp(Vector3d(0.1, -0.2, 0.3));
  T.translation() = Vector3d(5, -3, 2);
  return T;
}

TEST(StabilityGeometry, ColinearFiducialsAreRefused) {
  const std::vector<Vector3d> line = {Vector3d(0, 0, 0), Vector3d(10, 0, 0), Vector3d(25, 0, 0),
                                      Vector3d(-7, 0, 0)};
  auto r = fit_rigid(line, moved(line, some_motion()));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("ollinear"), std::string::npos) << r.status().message();
  // Nearly colinear (1 micrometre off a 25 mm line): refused or finite, never NaN.
  auto almost = line;
  almost[1].y() = 1e-3;
  auto r2 = fit_rigid(almost, moved(almost, some_motion()));
  if (r2.ok()) {
    EXPECT_TRUE(r2->T_to_from.matrix().allFinite());
  }
}

TEST(StabilityGeometry, CoplanarFiducialsFitExactly) {
  const std::vector<Vector3d> plane = {Vector3d(0, 0, 0), Vector3d(10, 0, 0), Vector3d(0, 15, 0),
                                       Vector3d(8, 9, 0)};
  auto r = fit_rigid(plane, moved(plane, some_motion()));
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_LT((r->T_to_from.matrix() - some_motion().matrix()).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_NEAR(r->T_to_from.linear().determinant(), 1.0, 1e-12) << "never the mirror image";
}

TEST(StabilityGeometry, RepeatedFiducials) {
  const std::vector<Vector3d> same(4, Vector3d(3, 4, 5));
  EXPECT_FALSE(fit_rigid(same, moved(same, some_motion())).ok()) << "one point repeated fixes no rotation";
  std::vector<Vector3d> with_repeats = {Vector3d(0, 0, 0), Vector3d(10, 0, 0), Vector3d(10, 0, 0),
                                        Vector3d(0, 12, 3)};
  auto r = fit_rigid(with_repeats, moved(with_repeats, some_motion()));
  ASSERT_TRUE(r.ok()) << "repeats among three distinct points are harmless";
  EXPECT_LT((r->T_to_from.matrix() - some_motion().matrix()).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_FALSE(fit_rigid({}, {}).ok());
  EXPECT_FALSE(fit_rigid(with_repeats, {Vector3d::Zero()}).ok()) << "mismatched counts";
}

TEST(StabilityGeometry, SourceOnTheDetectorPlaneIsRefused) {
  XrayView v = view_from(Vector3d(0, -1, 0));
  ASSERT_TRUE(v.validate().ok());
  // Move the source into the detector plane.
  v.source_mm = v.pixel00_mm + 30 * v.col_axis + 40 * v.row_axis;
  const auto s = v.validate();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("detector plane"), std::string::npos) << s.message();
  EXPECT_FALSE(triangulate(v, Vector2d(1, 1), view_from(Vector3d(1, 0, 0)), Vector2d(1, 1)).ok());
  EXPECT_FALSE(
      XrayView::isocentric("W", Vector3d::Zero(), Vector3d(1, 0, 0), Vector3d(0, 0, 1), 1000, 0.5, 8, 8, 1)
          .ok());
}

}  // namespace
}  // namespace lftrack::calib
