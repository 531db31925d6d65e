#include "lftrack/phantom/implanted_markers.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace lftrack::phantom {
namespace {

using tracking::HounsfieldUnits;
using tracking::MuVolume;
using tracking::ScalarVolume;

// A 40 mm cube of 1 mm voxels centred on the CT origin, all zero.
MuVolume empty_cube() {
  MuVolume v;
  v.geometry.size = {40, 40, 40};
  v.geometry.origin_mm = {-19.5, -19.5, -19.5};
  v.values.assign(64000, 0.f);
  return v;
}

TEST(InsertMarkers, ASphereOfTheRightVolumeAtTheRightPlace) {
  MuVolume v = empty_cube();
  const Eigen::Vector3d centre(3.3, -2.2, 1.6);
  insert_markers(&v, {centre}, 2.0, 1.0f);
  double total = 0;
  Eigen::Vector3d weighted = Eigen::Vector3d::Zero();
  for (int k = 0; k < 40; ++k)
    for (int j = 0; j < 40; ++j)
      for (int i = 0; i < 40; ++i) {
        total += v.at(i, j, k);
        weighted += v.at(i, j, k) * (v.geometry.ct_from_index() * Eigen::Vector3d(i, j, k));
      }
  EXPECT_NEAR(total, 4.0 / 3.0 * M_PI * 8.0, 0.6);  // mm^3 at 1 mm voxels
  EXPECT_LT((weighted / total - centre).norm(), 0.05);
}

// A marker replaces what the voxel held in proportion to its share: a voxel wholly inside reads
// the marker's value, one far outside keeps its own; a CT takes the HU the scanner clips steel to.
TEST(InsertMarkers, ReplacesTheVoxelsValueByItsShareAndLeavesTheRest) {
  ScalarVolume<HounsfieldUnits> ct;
  ct.geometry.size = {40, 40, 40};
  ct.geometry.origin_mm = {-19.5, -19.5, -19.5};
  ct.values.assign(64000, 40.f);  // soft tissue
  insert_markers(&ct, {Eigen::Vector3d(0.5, 0.5, 0.5)}, 3.0, kMarkerHu);
  EXPECT_FLOAT_EQ(ct.at(20, 20, 20), kMarkerHu) << "the voxel at the centre is wholly steel";
  EXPECT_FLOAT_EQ(ct.at(5, 5, 5), 40.f) << "far from the marker";
  // 2.5-3.5 mm from the centre along x, 1 mm wide: 32 of its 4^3 sub-samples lie inside 3 mm.
  EXPECT_FLOAT_EQ(ct.at(23, 20, 20), 0.5f * 40.f + 0.5f * kMarkerHu) << "blended by its share, not added";
}

// A marker partly or wholly outside the volume writes what is inside and nothing else.
TEST(InsertMarkers, AMarkerOutsideTheVolumeWritesOnlyWhatIsInside) {
  MuVolume v = empty_cube();
  insert_markers(&v, {Eigen::Vector3d(100, 0, 0), Eigen::Vector3d(20.5, 0, 0)}, 2.0, kSteelMuPerMm);
  double total = 0;
  for (float x : v.values) total += x;
  // The cube ends at x = 20 mm: of the sphere at 20.5 mm only a cap 1.5 mm high is inside,
  // pi h^2 (3 r - h) / 3 = 10.6 mm^3 (1 mm voxels); the one at 100 mm writes nothing.
  EXPECT_NEAR(total, M_PI * 1.5 * 1.5 * (3 * 2.0 - 1.5) / 3 * kSteelMuPerMm, 0.6 * kSteelMuPerMm);
}

}  // namespace
}  // namespace lftrack::phantom
