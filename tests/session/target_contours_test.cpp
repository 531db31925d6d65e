// A target's contours (target_contours.cpp): checked, boxed and filled on a CT's grid.

#include "lftrack/session/target_contours.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace lftrack::session {
namespace {

using Eigen::Vector3d;

TargetPolygon rectangle(double x0, double y0, double x1, double y1, double z) {
  return {{{x0, y0, z}, {x1, y0, z}, {x1, y1, z}, {x0, y1, z}}};
}

TargetPolygon circle(const Vector3d& centre, double radius, int points) {
  TargetPolygon p;
  for (int i = 0; i < points; ++i) {
    const double a = 2 * M_PI * i / points;
    p.points_ct_mm.push_back(centre + Vector3d(radius * std::cos(a), radius * std::sin(a), 0));
  }
  return p;
}

tracking::VolumeGeometry grid_1mm(int n) {
  tracking::VolumeGeometry g;
  g.size = Eigen::Vector3i(n, n, n);
  g.spacing_mm = Vector3d::Ones();
  g.origin_mm = Vector3d::Zero();
  return g;
}

TEST(TargetContours, ASquareOnThreeSlicesFillsItsVoxels) {
  std::vector<TargetPolygon> target;
  for (int z = 10; z <= 12; ++z) target.push_back(rectangle(4.5, 4.5, 14.5, 9.5, z));  // 10 x 5 voxel centres
  ASSERT_TRUE(check_target_polygons(target, "box").ok());
  auto mask = rasterise_target(target, grid_1mm(32), "box");
  ASSERT_TRUE(mask.ok()) << mask.status().message();
  EXPECT_EQ(mask->voxels_inside, 10 * 5 * 3);
  EXPECT_NEAR(mask->volume_cc(), 0.150, 1e-9);
  EXPECT_EQ(mask->inside[5 + 32 * (5 + 32 * 10)], 1);
  EXPECT_EQ(mask->inside[4 + 32 * (5 + 32 * 10)], 0);
  EXPECT_EQ(mask->inside[5 + 32 * (5 + 32 * 13)], 0) << "no contour on slice 13";
  const TargetBox box = target_box(target);
  EXPECT_TRUE(box.centre_ct_mm().isApprox(Vector3d(9.5, 7, 11)));
  EXPECT_TRUE(box.size_mm().isApprox(Vector3d(10, 5, 2)));
}

TEST(TargetContours, AContourInsideAnotherIsAHole) {
  const std::vector<TargetPolygon> ring = {rectangle(0.5, 0.5, 20.5, 20.5, 5), rectangle(5.5, 5.5, 15.5, 15.5, 5)};
  auto mask = rasterise_target(ring, grid_1mm(32), "ring");
  ASSERT_TRUE(mask.ok()) << mask.status().message();
  EXPECT_EQ(mask->voxels_inside, 20 * 20 - 10 * 10);
  EXPECT_EQ(mask->inside[10 + 32 * (10 + 32 * 5)], 0);
}

TEST(TargetContours, ACircleOfAHundredThousandPointsHasTheAreaOfACircle) {
  const std::vector<TargetPolygon> disc = {circle({64, 64, 3}, 40, 100000)};
  ASSERT_TRUE(check_target_polygons(disc, "disc").ok());
  auto mask = rasterise_target(disc, grid_1mm(128), "disc");
  ASSERT_TRUE(mask.ok());
  EXPECT_NEAR(double(mask->voxels_inside), M_PI * 40 * 40, 0.01 * M_PI * 40 * 40);
}

TEST(TargetContours, ContoursThatEncloseNothingAreRefusedWithTheReason) {
  const auto refused = [](const std::vector<TargetPolygon>& p, const std::string& why) {
    const Status s = check_target_polygons(p, "PTV");
    ASSERT_FALSE(s.ok()) << why;
    EXPECT_NE(s.message().find("target 'PTV'"), std::string::npos) << s.message();
    EXPECT_NE(s.message().find(why), std::string::npos) << s.message();
  };
  refused({}, "has no contour");
  refused({{{{1, 1, 1}}}}, "1 distinct point(s)");
  refused({{{{1, 1, 1}, {2, 2, 1}, {1, 1, 1}, {2, 2, 1}}}}, "2 distinct point(s)");
  refused({{{{0, 0, 1}, {1, 1, 1}, {2, 2, 1}}}}, "encloses no area");
  refused({{{{0, 0, 0}, {10, 0, 0}, {10, 10, 5}, {0, 10, 0}}}}, "is not planar");
  refused({{{{0, 0, 1}, {10, 10, 1}, {10, 0, 1}, {0, 10, 1}}}}, "crosses itself");  // a bow tie
  refused({rectangle(0, 0, 5, 5, 1), {{{0, 0, 1}, {1, 0, 1}, {NAN, 1, 1}}}}, "contour 2: a point that is not a finite");
  // Touching itself at a corner (a figure eight) has no single inside either.
  refused({{{{0, 0, 1}, {4, 0, 1}, {2, 2, 1}, {4, 4, 1}, {0, 4, 1}, {2, 2, 1}}}}, "crosses itself");
}

TEST(TargetContours, AContourAcrossTheSlicesIsRefused) {
  const std::vector<TargetPolygon> sagittal = {{{{5, 0, 0}, {5, 10, 0}, {5, 10, 10}, {5, 0, 10}}}};
  ASSERT_TRUE(check_target_polygons(sagittal, "sag").ok()) << "a planar, simple contour";
  auto mask = rasterise_target(sagittal, grid_1mm(16), "sag");
  ASSERT_FALSE(mask.ok());
  EXPECT_NE(mask.status().message().find("does not lie in one of the CT's slices"), std::string::npos);
}

}  // namespace
}  // namespace lftrack::session
