#include "lftrack/tracking/target_error.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace lftrack::tracking {
namespace {

VolumeGeometry grid() {
  VolumeGeometry g;
  g.size = {100, 100, 60};
  g.spacing_mm = {1.0, 1.0, 2.0};
  g.origin_mm = {-50, -50, -60};
  return g;
}

TEST(TargetError, ZeroAtGoldAndTheShiftForATranslation) {
  TreBox box;
  box.edge_mm = 20;
  const Pose gold = Pose::Identity();
  const Tre zero = target_registration_error(gold, gold, grid(), box);
  EXPECT_EQ(zero.max_mm, 0);
  EXPECT_EQ(zero.points, 21 * 21 * 11);  // voxel centres in [-10, 10] mm
  Pose moved = gold;
  moved.translation() = Eigen::Vector3d(3, 4, 0);
  const Tre t = target_registration_error(moved, gold, grid(), box);
  EXPECT_NEAR(t.mean_mm, 5, 1e-9);
  EXPECT_NEAR(t.max_mm, 5, 1e-9);
}

TEST(TargetError, RotationAboutTheBoxCentreGrowsTowardsTheCorners) {
  TreBox box;
  box.edge_mm = 20;
  Pose turned = Pose::Identity();
  const double angle = deg_to_rad(2.0);
  turned.linear() = rotation_exp(Eigen::Vector3d(0, 0, angle));
  const Tre t = target_registration_error(turned, Pose::Identity(), grid(), box);
  // Farthest points from the z axis: the box's vertical edges, 10 sqrt(2) mm away.
  EXPECT_NEAR(t.max_mm, 2 * std::sin(angle / 2) * 10 * std::sqrt(2.0), 1e-9);
  EXPECT_GT(t.mean_mm, 0);
  EXPECT_LT(t.mean_mm, t.max_mm);
}

TEST(TargetError, ABoxBetweenVoxelCentresUsesItsCentre) {
  TreBox box;
  box.centre_ct_mm = {0.5, 0.5, 1.0};
  box.edge_mm = 0.1;
  Pose moved = Pose::Identity();
  moved.translation() = Eigen::Vector3d(1, 0, 0);
  const Tre t = target_registration_error(moved, Pose::Identity(), grid(), box);
  EXPECT_EQ(t.points, 1);
  EXPECT_NEAR(t.mean_mm, 1, 1e-12);
}

}  // namespace
}  // namespace lftrack::tracking
