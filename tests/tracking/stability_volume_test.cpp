// Numerical stability at the extremes: volumes (docs/stability.md, "Volumes"). Degenerate grids
// render finite DRRs; extreme and invalid values are clamped or refused, never passed on as NaN.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/octree_volume.hpp"
#include "lftrack/tracking/ray_integrals.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

std::shared_ptr<const MuVolume> volume_of(Eigen::Vector3i size, Vector3d spacing, float mu) {
  auto v = std::make_shared<MuVolume>();
  v->geometry.size = size;
  v->geometry.spacing_mm = spacing;
  v->geometry.origin_mm = -0.5 * (size.cast<double>() - Vector3d::Ones()).cwiseProduct(spacing);  // centred
  v->values.assign(std::size_t(v->geometry.voxel_count()), mu);
  return v;
}

// A DRR of the volume (centred at the origin) by every volume renderer: finite, >= 0, and the
// central pixel's ray sees the volume where it should.
void expect_finite_drrs(const std::shared_ptr<const MuVolume>& v, double expected_centre, double tolerance) {
  const XrayView view = *XrayView::isocentric("A", Vector3d::Zero(), Vector3d(0, -1, 0), Vector3d(0, 0, 1),
                                              500, 1000, 33, 33, 0.05);
  for (const char* name : {"siddon", "trilinear", "octree"}) {
    auto r = make_renderer(name, v);
    ASSERT_TRUE(r.ok()) << name << ": " << r.status().message();
    Image<float> drr(33, 33, -1.0f);
    ASSERT_TRUE((*r)->render(Pose::Identity(), view, PixelWindow::full(33, 33), drr.view()).ok()) << name;
    for (float p : drr.pixels()) ASSERT_TRUE(std::isfinite(p) && p >= 0) << name;
    EXPECT_NEAR(drr.at(16, 16), expected_centre, tolerance) << name;
  }
}

TEST(StabilityVolume, OneVoxel) {
  const auto v = volume_of({1, 1, 1}, {2, 2, 2}, 0.02f);
  ASSERT_TRUE(v->geometry.validate().ok());
  expect_finite_drrs(v, 0.02 * 2, 1e-6);  // the central ray crosses the 2 mm voxel
  auto tree = OctreeVolume::build(*v, 0.0);
  ASSERT_TRUE(tree.ok());
  EXPECT_EQ(tree->leaf_count(), 1u);
}

TEST(StabilityVolume, OneSlice) {
  const auto v = volume_of({64, 64, 1}, {1, 1, 3}, 0.02f);
  expect_finite_drrs(v, 0.02 * 64, 1e-4);  // the beam runs along j: 64 voxels of 1 mm
}

TEST(StabilityVolume, NeedleVoxelsOf0p05By0p05By10Mm) {
  const auto v = volume_of({40, 40, 4}, {0.05, 0.05, 10}, 0.02f);
  ASSERT_TRUE(v->geometry.validate().ok());
  expect_finite_drrs(v, 0.02 * 40 * 0.05, 1e-5);
}

TEST(StabilityVolume, HuFarBelowMinus1000IsAirAndMetalIsDense) {
  CtVolume ct;
  ct.geometry.size = {6, 1, 1};
  ct.values = {-1e6f, -3024.0f, -1000.0f, 0.0f, 4000.0f, 3.0e4f};
  const MuVolume mu = to_attenuation(ct);
  EXPECT_EQ(mu.values[0], 0.0f);
  EXPECT_EQ(mu.values[1], 0.0f);
  EXPECT_EQ(mu.values[2], 0.0f);
  EXPECT_FLOAT_EQ(mu.values[3], float(kDefaultMuWaterPerMm));
  EXPECT_FLOAT_EQ(mu.values[4], float(5 * kDefaultMuWaterPerMm));  // metal: 5 x water
  EXPECT_TRUE(std::isfinite(mu.values[5]));
  EXPECT_TRUE(check_attenuation_volume(mu).ok());
}

TEST(StabilityVolume, NanVoxelsNeverReachADrr) {
  CtVolume ct;
  ct.geometry.size = {4, 1, 1};
  ct.values = {0.0f, std::nanf(""), std::numeric_limits<float>::infinity(),
               -std::numeric_limits<float>::infinity()};
  const MuVolume mu = to_attenuation(ct);
  for (float v : mu.values) EXPECT_TRUE(std::isfinite(v) && v >= 0);
  EXPECT_EQ(mu.values[1], 0.0f);

  // An attenuation volume holding NaN (built by hand, not by to_attenuation) is refused by every
  // renderer and by the octree, with the count and the first index.
  auto bad = std::make_shared<MuVolume>(*volume_of({5, 5, 5}, {1, 1, 1}, 0.02f));
  bad->values[7] = std::nanf("");
  bad->values[9] = -0.1f;
  for (const char* name : {"siddon", "trilinear", "octree"}) {
    auto r = make_renderer(name, bad);
    ASSERT_FALSE(r.ok()) << name;
    EXPECT_NE(r.status().message().find("2 value(s)"), std::string::npos) << r.status().message();
    EXPECT_NE(r.status().message().find("index 7"), std::string::npos) << r.status().message();
  }
  EXPECT_FALSE(OctreeVolume::build(*bad, 0.1).ok());
}

TEST(StabilityVolume, InvalidGridsAreRefused) {
  for (const auto& [size, spacing] : {std::pair{Eigen::Vector3i(0, 4, 4), Vector3d(1, 1, 1)},
                                      std::pair{Eigen::Vector3i(4, 4, 4), Vector3d(0, 1, 1)},
                                      std::pair{Eigen::Vector3i(4, 4, 4), Vector3d(1e-5, 1, 1)},
                                      std::pair{Eigen::Vector3i(4, 4, 4), Vector3d(std::nan(""), 1, 1)}}) {
    VolumeGeometry g;
    g.size = size;
    g.spacing_mm = spacing;
    EXPECT_FALSE(g.validate().ok()) << size.transpose() << " / " << spacing.transpose();
  }
}

}  // namespace
}  // namespace lftrack::tracking
