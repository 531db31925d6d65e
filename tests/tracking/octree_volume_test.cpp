// OctreeVolume: the paper's compression, its ordered leaf list, decompression, and the leaf-by-leaf
// line integral against Siddon on the decompressed volume.

#include "lftrack/tracking/octree_volume.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "fixtures.hpp"
#include "lftrack/tracking/ray_integrals.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

// A volume of piecewise-constant blocks (what an octree compresses) with a noisy corner.
MuVolume blocky_volume(Eigen::Vector3i size, std::uint64_t seed = 3) {
  MuVolume v;
  v.geometry.size = size;
  v.geometry.spacing_mm = {0.8, 1.1, 2.0};
  v.values.resize(std::size_t(v.geometry.voxel_count()));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> noise(0.0f, 0.01f);
  for (int k = 0; k < size.z(); ++k)
    for (int j = 0; j < size.y(); ++j)
      for (int i = 0; i < size.x(); ++i) {
        float mu = (i / 8 + j / 4 + k / 2) % 3 == 0 ? 0.02f : 0.0f;
        if (i < 5 && j < 5 && k < 5) mu += noise(rng);
        v.at(i, j, k) = mu;
      }
  return v;
}

TEST(Octree, PivotZeroIsLosslessForAnySize) {
  for (Eigen::Vector3i size :
       {Eigen::Vector3i(16, 16, 16), Eigen::Vector3i(5, 3, 7), Eigen::Vector3i(33, 20, 9),
        Eigen::Vector3i(1, 1, 1), Eigen::Vector3i(1, 40, 1)}) {
    const MuVolume v = blocky_volume(size);
    auto tree = OctreeVolume::build(v, 0.0);
    ASSERT_TRUE(tree.ok()) << tree.status().message();
    EXPECT_EQ(tree->decompress().values, v.values) << size.transpose();
    EXPECT_LE(tree->leaf_count(), std::size_t(v.geometry.voxel_count()));
  }
}

TEST(Octree, UniformRegionsBecomeOneLeaf) {
  MuVolume v = blocky_volume({32, 32, 32});
  std::fill(v.values.begin(), v.values.end(), 0.017f);
  auto tree = OctreeVolume::build(v, 0.0);
  ASSERT_TRUE(tree.ok());
  ASSERT_EQ(tree->leaf_count(), 1u);
  EXPECT_EQ(tree->leaf_levels()[0], 5);
  EXPECT_EQ(tree->leaf_values()[0], 0.017f);
  EXPECT_NEAR(tree->cell_reduction(), 1.0 - 1.0 / (32 * 32 * 32), 1e-12);
  // The blocky volume compresses well, losslessly.
  auto blocks = OctreeVolume::build(blocky_volume({32, 32, 32}), 0.0);
  ASSERT_TRUE(blocks.ok());
  EXPECT_GT(blocks->cell_reduction(), 0.5);
}

TEST(Octree, EveryVoxelIsWithinHalfTheThresholdAndLeavesFallWithThePivot) {
  const MuVolume v = blocky_volume({40, 24, 17});
  std::size_t last = std::size_t(-1);
  for (double pivot : {0.0, 0.001, 0.01, 0.1, 0.3, 1.0}) {
    auto tree = OctreeVolume::build(v, pivot);
    ASSERT_TRUE(tree.ok());
    const MuVolume back = tree->decompress();
    double worst = 0;
    for (std::size_t n = 0; n < v.values.size(); ++n)
      worst = std::max(worst, std::abs(double(back.values[n]) - double(v.values[n])));
    EXPECT_LE(worst, 0.5 * tree->threshold_per_mm() + 1e-7) << pivot;
    EXPECT_LE(tree->leaf_count(), last) << pivot;
    last = tree->leaf_count();
  }
  auto one = OctreeVolume::build(v, 1.0);  // the whole range fits one leaf
  ASSERT_TRUE(one.ok());
  EXPECT_EQ(one->leaf_count(), 1u);
}

TEST(Octree, LeafListRoundTripsAndDamagedListsAreRefused) {
  const MuVolume v = blocky_volume({20, 12, 9});
  auto tree = OctreeVolume::build(v, 0.0);
  ASSERT_TRUE(tree.ok());
  auto again = OctreeVolume::from_leaves(v.geometry, tree->leaf_levels(), tree->leaf_values());
  ASSERT_TRUE(again.ok()) << again.status().message();
  EXPECT_EQ(again->decompress().values, v.values);

  auto levels = tree->leaf_levels();
  auto values = tree->leaf_values();
  levels.pop_back();
  values.pop_back();
  auto short_list = OctreeVolume::from_leaves(v.geometry, levels, values);
  ASSERT_FALSE(short_list.ok());
  EXPECT_NE(short_list.status().message().find("ends before"), std::string::npos);
  levels = tree->leaf_levels();
  values = tree->leaf_values();
  levels.push_back(0);
  values.push_back(0);
  auto long_list = OctreeVolume::from_leaves(v.geometry, levels, values);
  ASSERT_FALSE(long_list.ok());
  EXPECT_NE(long_list.status().message().find("left over"), std::string::npos);
  levels = tree->leaf_levels();
  levels[0] = 9;  // larger than the node it sits in
  EXPECT_FALSE(OctreeVolume::from_leaves(v.geometry, levels, tree->leaf_values()).ok());
  values = tree->leaf_values();
  values[1] = std::nanf("");
  EXPECT_FALSE(OctreeVolume::from_leaves(v.geometry, tree->leaf_levels(), values).ok());
  EXPECT_FALSE(OctreeVolume::from_leaves(v.geometry, tree->leaf_levels(), {}).ok());
}

TEST(Octree, RefusesBadPivotsAndNonFiniteVolumes) {
  MuVolume v = blocky_volume({8, 8, 8});
  EXPECT_FALSE(OctreeVolume::build(v, -0.1).ok());
  EXPECT_FALSE(OctreeVolume::build(v, 1.5).ok());
  EXPECT_FALSE(OctreeVolume::build(v, std::nan("")).ok());
  v.values[17] = std::nanf("");
  auto nan_voxel = OctreeVolume::build(v, 0.1);
  ASSERT_FALSE(nan_voxel.ok());
  EXPECT_NE(nan_voxel.status().message().find("NaN"), std::string::npos);
  v.values.pop_back();
  EXPECT_FALSE(OctreeVolume::build(v, 0.1).ok());
}

// The leaf walk equals Siddon through the decompressed volume, for rays in every direction,
// along faces, parallel to axes, and from inside the volume.
TEST(Octree, LineIntegralEqualsSiddonThroughTheDecompressedVolume) {
  for (double pivot : {0.0, 0.05}) {
    const MuVolume v = blocky_volume({37, 22, 13});
    auto tree = OctreeVolume::build(v, pivot);
    ASSERT_TRUE(tree.ok());
    const MuVolume back = tree->decompress();
    const GridRayCaster caster(back);
    const OctreeNodes nodes(*tree);
    const Vector3d extent = v.geometry.extent_mm();
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(-0.3, 1.3);
    std::vector<std::pair<Vector3d, Vector3d>> rays;
    for (int n = 0; n < 400; ++n) {
      const Vector3d a(u(rng) * extent.x(), u(rng) * extent.y(), u(rng) * extent.z());
      const Vector3d b(u(rng) * extent.x(), u(rng) * extent.y(), u(rng) * extent.z());
      rays.emplace_back(a, b);
    }
    const Vector3d s = v.geometry.spacing_mm;
    rays.emplace_back(Vector3d(-5, 2.5 * s.y(), 1.5 * s.z()),
                      Vector3d(100, 2.5 * s.y(), 1.5 * s.z()));                                 // a face
    rays.emplace_back(Vector3d(3 * s.x(), -5, 4 * s.z()), Vector3d(3 * s.x(), 50, 4 * s.z()));  // along j
    rays.emplace_back(Vector3d(10, 10, 10), Vector3d(-40, -30, -20));                           // from inside
    rays.emplace_back(Vector3d(-0.5 * s.x(), -0.5 * s.y(), -0.5 * s.z()), Vector3d(40, 30, 30));  // a corner
    for (const auto& [a, b] : rays) {
      const double expected = caster.siddon(a, b);
      EXPECT_NEAR(octree_line_integral(nodes, v.geometry, a, b), expected, 1e-9 + 1e-6 * expected)
          << pivot << ": " << a.transpose() << " -> " << b.transpose();
    }
    EXPECT_EQ(octree_line_integral(nodes, v.geometry, Vector3d(1, 1, 1), Vector3d(1, 1, 1)), 0.0);
    EXPECT_EQ(octree_line_integral(nodes, v.geometry, Vector3d(1, 1, std::nan("")), Vector3d(1, 1, 1)), 0.0);
  }
}

// The traversal layout finds the leaf of every voxel.
TEST(Octree, TraversalLayoutFindsEveryVoxelsLeaf) {
  const MuVolume v = blocky_volume({19, 10, 6});
  auto tree = OctreeVolume::build(v, 0.0);
  ASSERT_TRUE(tree.ok());
  const OctreeNodes nodes(*tree);
  for (int k = 0; k < 6; ++k)
    for (int j = 0; j < 10; ++j)
      for (int i = 0; i < 19; ++i) {
        int level = -1;
        ASSERT_EQ(nodes.leaf_at(i, j, k, &level), v.at(i, j, k)) << i << "," << j << "," << k;
        ASSERT_GE(level, 0);
      }
  EXPECT_GT(nodes.bytes(), 0u);
}

}  // namespace
}  // namespace lftrack::tracking
