#include <gtest/gtest.h>

#include <cmath>

#include "lftrack/tracking/volume.hpp"

namespace lftrack::tracking {
namespace {

VolumeGeometry oblique_geometry() {
  VolumeGeometry g;
  g.size = {10, 20, 30};
  g.spacing_mm = {0.5, 0.75, 2.0};
  g.origin_mm = {-100, 50, 7};
  g.direction = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  return g;
}

TEST(VolumeGeometry, IndexAndCtFrameRoundTrip) {
  const VolumeGeometry g = oblique_geometry();
  const Eigen::Vector3d idx(3.25, 7.5, 12.0);
  const Eigen::Vector3d p = g.ct_from_index() * idx;
  EXPECT_TRUE((g.index_from_ct() * p).isApprox(idx, 1e-12));
  // Voxel (0,0,0) is at the origin; one step in i moves spacing_i along direction column 0.
  EXPECT_TRUE((g.ct_from_index() * Eigen::Vector3d::Zero()).isApprox(g.origin_mm));
  EXPECT_TRUE(
      (g.ct_from_index() * Eigen::Vector3d::UnitX() - g.origin_mm).isApprox(0.5 * g.direction.col(0)));
}

TEST(VolumeGeometry, GridFrameIsRigidAndScaledBySpacing) {
  const VolumeGeometry g = oblique_geometry();
  const Eigen::Vector3d idx(2, 3, 4);
  const Eigen::Vector3d in_grid = g.grid_from_ct() * (g.ct_from_index() * idx);
  EXPECT_TRUE(in_grid.isApprox(idx.cwiseProduct(g.spacing_mm), 1e-12));
}

TEST(VolumeGeometry, CentreIsTheMiddleOfTheVoxelCentres) {
  VolumeGeometry g;
  g.size = {3, 5, 7};
  g.origin_mm = {1, 2, 3};
  EXPECT_TRUE(g.centre_mm().isApprox(Eigen::Vector3d(2, 4, 6)));
}

TEST(VolumeGeometry, ValidateRejectsEachBadClass) {
  auto expect_bad = [](VolumeGeometry g, const char* what) {
    const Status s = g.validate();
    EXPECT_FALSE(s.ok()) << what;
    EXPECT_FALSE(s.message().empty()) << what;
  };
  VolumeGeometry g = oblique_geometry();
  EXPECT_TRUE(g.validate().ok());
  {
    auto b = g;
    b.size.y() = 0;
    expect_bad(b, "zero size");
  }
  {
    auto b = g;
    b.size.x() = 100000;
    expect_bad(b, "absurd size");
  }
  {
    auto b = g;
    b.size = {8192, 8192, 8192};
    expect_bad(b, "too many voxels");
  }
  {
    auto b = g;
    b.spacing_mm.z() = std::nan("");
    expect_bad(b, "NaN spacing");
  }
  {
    auto b = g;
    b.spacing_mm.x() = -1;
    expect_bad(b, "negative spacing");
  }
  {
    auto b = g;
    b.spacing_mm.x() = 1e6;
    expect_bad(b, "absurd spacing");
  }
  {
    auto b = g;
    b.origin_mm.y() = INFINITY;
    expect_bad(b, "infinite origin");
  }
  {
    auto b = g;
    b.direction(0, 1) += 0.3;
    expect_bad(b, "sheared axes");
  }
}

TEST(BlockAveraged, MeansOverBlocksWithAirBeyondTheLastVoxelAndTheSameCorner) {
  MuVolume mu;
  mu.geometry = oblique_geometry();
  mu.geometry.size = {5, 4, 3};
  mu.values.resize(60);
  for (std::size_t i = 0; i < mu.values.size(); ++i) mu.values[i] = 0.001f * float(i);
  const MuVolume coarse = block_averaged(mu, {2, 2, 2});
  EXPECT_EQ(coarse.geometry.size, Eigen::Vector3i(3, 2, 2));
  EXPECT_TRUE(coarse.geometry.spacing_mm.isApprox(2 * mu.geometry.spacing_mm));
  // Block (0,0,0)'s centre is the mean of its eight voxels' centres.
  const Eigen::Vector3d centre = mu.geometry.ct_from_index() * Eigen::Vector3d(0.5, 0.5, 0.5);
  EXPECT_LT((coarse.geometry.ct_from_index() * Eigen::Vector3d::Zero() - centre).norm(), 1e-9);
  float block = 0;
  for (int k = 0; k < 2; ++k)
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 2; ++i) block += mu.at(i, j, k);
  EXPECT_FLOAT_EQ(coarse.at(0, 0, 0), block / 8);
  // The last block along i has one voxel of five: the other half is air.
  EXPECT_FLOAT_EQ(coarse.at(2, 0, 0), (mu.at(4, 0, 0) + mu.at(4, 1, 0) + mu.at(4, 0, 1) + mu.at(4, 1, 1)) / 8);
  // The integral of mu over the volume is kept.
  double fine_sum = 0, coarse_sum = 0;
  for (float v : mu.values) fine_sum += v;
  for (float v : coarse.values) coarse_sum += 8.0 * v;
  EXPECT_NEAR(coarse_sum, fine_sum, 1e-4);
  EXPECT_TRUE(check_attenuation_volume(coarse).ok());
  EXPECT_EQ(block_averaged(mu, {1, 1, 1}).values, mu.values) << "a factor of one is a copy";
}

TEST(Attenuation, FollowsTheDesignFormulaAndClampsAtZero) {
  CtVolume ct;
  ct.geometry.size = {4, 1, 1};
  ct.values = {-1000.0f, -1200.0f, 0.0f, 1000.0f};
  const MuVolume mu = to_attenuation(ct, 0.02);
  EXPECT_FLOAT_EQ(mu.values[0], 0.0f);
  EXPECT_FLOAT_EQ(mu.values[1], 0.0f);  // below air: clamped, never negative
  EXPECT_FLOAT_EQ(mu.values[2], 0.02f);
  EXPECT_FLOAT_EQ(mu.values[3], 0.04f);
}

}  // namespace
}  // namespace lftrack::tracking
