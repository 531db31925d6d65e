// Numerical stability at the extremes: rays (docs/stability.md, "Rays"), through every line-integral
// kernel: Siddon, trilinear and the octree walk. Each returns a finite value >= 0.

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>

#include "fixtures.hpp"
#include "lftrack/tracking/octree_volume.hpp"
#include "lftrack/tracking/ray_integrals.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

using test::uniform_box;

// The three kernels on one volume.
struct Kernels {
  explicit Kernels(const MuVolume& v)
      : volume(v), caster(v), tree(*OctreeVolume::build(v, 0.0)), nodes(tree) {}
  std::vector<std::pair<const char*, std::function<double(const Vector3d&, const Vector3d&)>>> all() const {
    return {
        {"siddon", [this](const Vector3d& a, const Vector3d& b) { return caster.siddon(a, b); }},
        {"trilinear", [this](const Vector3d& a, const Vector3d& b) { return caster.trilinear(a, b, 0.25); }},
        {"octree", [this](const Vector3d& a, const Vector3d& b) {
           return octree_line_integral(nodes, volume.geometry, a, b);
         }}};
  }
  const MuVolume& volume;
  GridRayCaster caster;
  OctreeVolume tree;
  OctreeNodes nodes;
};

TEST(StabilityRay, ParallelToEachAxisGivesTheChord) {
  const MuVolume v = uniform_box({10, 12, 14}, {1.0, 0.5, 2.0}, 0.02f);
  const Kernels k(v);
  for (int axis = 0; axis < 3; ++axis) {
    Vector3d a(2.2, 2.2, 6.1), b = a;
    a[axis] = -100;
    b[axis] = 100;
    const double chord = v.geometry.extent_mm()[axis];
    for (const auto& [name, f] : k.all())
      EXPECT_NEAR(f(a, b), double(0.02f) * chord, 1e-9) << name << " axis " << axis;
  }
}

TEST(StabilityRay, ThroughEdgesAndCornersIsFiniteAndBounded) {
  const MuVolume v = uniform_box({8, 8, 8}, {1, 1, 1}, 0.03f);
  const Kernels k(v);
  const Vector3d lo(-0.5, -0.5, -0.5), hi(7.5, 7.5, 7.5);
  const std::vector<std::pair<Vector3d, Vector3d>> rays = {
      {lo - Vector3d(1, 1, 1), hi + Vector3d(1, 1, 1)},      // corner to corner (the diagonal)
      {Vector3d(-5, -0.5, 3), Vector3d(20, -0.5, 3)},        // along the lower face y = lo
      {Vector3d(-5, 7.5, 3), Vector3d(20, 7.5, 3)},          // along the upper face: misses (half-open)
      {Vector3d(-5, -0.5, -0.5), Vector3d(20, -0.5, -0.5)},  // along a lower edge
      {Vector3d(3.5, -5, 2.5), Vector3d(3.5, 20, 2.5)},      // along interior voxel faces
      {Vector3d(lo.x(), lo.y(), -9), Vector3d(lo.x(), lo.y(), 9)},  // along the corner edge
      {lo, lo},                                                     // a corner, zero length
  };
  for (const auto& [a, b] : rays)
    for (const auto& [name, f] : k.all()) {
      const double p = f(a, b);
      ASSERT_TRUE(std::isfinite(p) && p >= 0) << name;
      EXPECT_LE(p, 0.03 * (b - a).norm() + 1e-9) << name;
    }
  EXPECT_NEAR(k.caster.siddon(rays[0].first, rays[0].second), double(0.03f) * std::sqrt(3.0) * 8, 1e-9);
  EXPECT_EQ(k.caster.siddon(rays[2].first, rays[2].second), 0.0);
}

TEST(StabilityRay, MissingInsideAndZeroLengthRays) {
  const MuVolume v = uniform_box({6, 6, 6}, {2, 2, 2}, 0.01f);
  const Kernels k(v);
  for (const auto& [name, f] : k.all()) {
    EXPECT_EQ(f(Vector3d(-10, -10, 50), Vector3d(40, -10, 50)), 0.0) << name;  // misses
    EXPECT_EQ(f(Vector3d(3, 3, 3), Vector3d(3, 3, 3)), 0.0) << name;           // zero length
    EXPECT_NEAR(f(Vector3d(5, 5, 5), Vector3d(5, 5, 100)), double(0.01f) * 6, 1e-9)
        << name;  // inside: z 5 -> 11
    const double nan = std::numeric_limits<double>::quiet_NaN(),
                 inf = std::numeric_limits<double>::infinity();
    EXPECT_EQ(f(Vector3d(nan, 0, 0), Vector3d(1, 1, 1)), 0.0) << name;
    EXPECT_EQ(f(Vector3d(-inf, 3, 3), Vector3d(inf, 3, 3)), 0.0) << name;
  }
}

// Long rays: 4096 voxels of 0.1 mm with values that do not sum exactly in float. Siddon
// accumulates in double; a float accumulator would lose about 1e-5 relative.
TEST(StabilityRay, LongRaysAccumulateInDouble) {
  MuVolume v = uniform_box({4096, 1, 1}, {0.1, 1, 1}, 0.0f);
  double exact = 0;
  float float_sum = 0;
  for (int i = 0; i < 4096; ++i) {
    const float mu = 0.0193f * (1.0f + 0.37f * float(std::sin(0.1 * i)));
    v.values[std::size_t(i)] = mu;
    exact += double(mu) * 0.1;
    float_sum += mu * 0.1f;
  }
  const Kernels k(v);
  const Vector3d a(-1, 0, 0), b(500, 0, 0);
  EXPECT_NEAR(k.caster.siddon(a, b), exact, 1e-12 * exact);
  EXPECT_NEAR(octree_line_integral(k.nodes, v.geometry, a, b), exact, 1e-12 * exact);
  const double float_error = std::abs(double(float_sum) - exact) / exact;
  RecordProperty("float_accumulator_relative_error", std::to_string(float_error));
  EXPECT_GT(float_error, 1e-9) << "a float accumulator would lose precision here";
}

}  // namespace
}  // namespace lftrack::tracking
