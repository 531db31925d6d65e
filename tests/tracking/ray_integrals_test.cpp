// Siddon-Jacobs and trilinear line integrals: analytic chords, degenerate rays, and a brute-force
// per-voxel cross-check.

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "fixtures.hpp"
#include "lftrack/tracking/ray_integrals.hpp"
#include "lftrack/tracking/random_draws.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

using test::uniform_box;

// Exact length of segment [p0, p1] inside the axis-aligned box [lo, hi] (slab method).
double chord_in_box(const Vector3d& p0, const Vector3d& p1, const Vector3d& lo, const Vector3d& hi) {
  const Vector3d d = p1 - p0;
  double a0 = 0, a1 = 1;
  for (int ax = 0; ax < 3; ++ax) {
    if (d[ax] == 0) {
      if (p0[ax] < lo[ax] || p0[ax] > hi[ax]) return 0;
      continue;
    }
    double t0 = (lo[ax] - p0[ax]) / d[ax], t1 = (hi[ax] - p0[ax]) / d[ax];
    if (t0 > t1) std::swap(t0, t1);
    a0 = std::max(a0, t0);
    a1 = std::min(a1, t1);
  }
  return a1 > a0 ? (a1 - a0) * d.norm() : 0.0;
}

// Brute force: sum over every voxel of mu times the segment's length inside that voxel's box.
double brute_force(const MuVolume& v, const Vector3d& p0, const Vector3d& p1) {
  const auto& g = v.geometry;
  double sum = 0;
  for (int k = 0; k < g.size.z(); ++k)
    for (int j = 0; j < g.size.y(); ++j)
      for (int i = 0; i < g.size.x(); ++i) {
        const float mu = v.at(i, j, k);
        if (mu == 0) continue;
        const Vector3d c = Vector3d(i, j, k).cwiseProduct(g.spacing_mm);
        sum += mu * chord_in_box(p0, p1, c - 0.5 * g.spacing_mm, c + 0.5 * g.spacing_mm);
      }
  return sum;
}

TEST(Siddon, HomogeneousBoxGivesChordTimesMu) {
  const MuVolume box = uniform_box({20, 16, 12}, {1.0, 1.25, 2.0}, 0.02f);
  const GridRayCaster caster(box);
  const Vector3d lo = -0.5 * box.geometry.spacing_mm;
  const Vector3d hi = lo + box.geometry.extent_mm();
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-60, 60);
  for (int n = 0; n < 500; ++n) {
    const Vector3d p0 = tracking::draw3(u, rng);
    const Vector3d p1 = tracking::draw3(u, rng);
    const double expected = 0.02 * chord_in_box(p0, p1, lo, hi);
    EXPECT_NEAR(caster.siddon(p0, p1), expected, 1e-5 * std::max(expected, 1e-3)) << n;
  }
}

TEST(Siddon, RaysParallelToEachAxis) {
  const MuVolume box = uniform_box({10, 10, 10}, {1, 1, 1}, 1.0f);
  const GridRayCaster caster(box);
  for (int ax = 0; ax < 3; ++ax) {
    Vector3d p0(4.2, 3.7, 5.1), p1 = p0;
    p0[ax] = -50;
    p1[ax] = 50;
    EXPECT_NEAR(caster.siddon(p0, p1), 10.0, 1e-9) << "axis " << ax;
    EXPECT_NEAR(caster.siddon(p1, p0), 10.0, 1e-9) << "reversed, axis " << ax;
  }
}

TEST(Siddon, RaysOnFacesAndEdgesFollowTheHalfOpenRule) {
  MuVolume v = uniform_box({4, 4, 4}, {1, 1, 1}, 0.0f);
  for (int i = 0; i < 4; ++i)
    for (int k = 0; k < 4; ++k) v.at(i, 0, k) = 1.0f;  // the j = 0 layer
  const GridRayCaster caster(v);
  // Along x on the volume's lower y face (y = -0.5): belongs to the j = 0 layer.
  EXPECT_NEAR(caster.siddon({-10, -0.5, 1.0}, {10, -0.5, 1.0}), 4.0, 1e-12);
  // On the shared face between j = 0 and j = 1 (y = 0.5): belongs to j = 1 (empty).
  EXPECT_NEAR(caster.siddon({-10, 0.5, 1.0}, {10, 0.5, 1.0}), 0.0, 1e-12);
  // On the volume's upper y face (y = 3.5): outside.
  MuVolume full = uniform_box({4, 4, 4}, {1, 1, 1}, 1.0f);
  const GridRayCaster full_caster(full);
  EXPECT_EQ(full_caster.siddon({-10, 3.5, 1.0}, {10, 3.5, 1.0}), 0.0);
  // Along an edge of the lower faces (y = -0.5, z = -0.5): inside, by the same rule.
  EXPECT_NEAR(full_caster.siddon({-10, -0.5, -0.5}, {10, -0.5, -0.5}), 4.0, 1e-12);
  // Through a corner diagonally: the full diagonal of the cube.
  EXPECT_NEAR(full_caster.siddon({-1.5, -1.5, -1.5}, {4.5, 4.5, 4.5}), 4.0 * std::sqrt(3.0), 1e-9);
  // Grazing through one corner point only: zero length.
  EXPECT_NEAR(full_caster.siddon({-1.5, -1.5, 0.5}, {0.5, 0.5, -1.5}), 0.0, 1e-9);
}

TEST(Siddon, MissingZeroLengthAndInsideRays) {
  const MuVolume box = uniform_box({10, 10, 10}, {1, 1, 1}, 1.0f);
  const GridRayCaster caster(box);
  EXPECT_EQ(caster.siddon({-20, 20, 3}, {20, 20, 3}), 0.0);            // misses
  EXPECT_EQ(caster.siddon({3, 3, 3}, {3, 3, 3}), 0.0);                 // zero length
  EXPECT_NEAR(caster.siddon({4.5, 2, 2}, {20, 2, 2}), 5.0, 1e-12);     // starts inside
  EXPECT_NEAR(caster.siddon({1.0, 2, 2}, {3.25, 2, 2}), 2.25, 1e-12);  // wholly inside
  EXPECT_NEAR(caster.siddon({-20, 2, 2}, {4.5, 2, 2}), 5.0, 1e-12);    // ends inside
  const double nan = std::nan("");
  EXPECT_EQ(caster.siddon({nan, 2, 2}, {4.5, 2, 2}), 0.0);  // NaN: no ray
}

// siddon_batch (sixteen AVX-512 or AVX2 lanes, each kernel the CPU has) against siddon() one ray at a time:
// the same bits for every ray, including rays that miss, start or end inside, run along faces,
// edges and axes, or have zero length, and a count that leaves a partial group of lanes.
TEST(SiddonBatch, EqualsTheScalarWalkBitForBit) {
  MuVolume v = uniform_box({23, 17, 9}, {1.1, 0.9, 2.5}, 0.0f);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> value(0.0f, 0.05f);
  for (float& mu : v.values) mu = value(rng);
  const GridRayCaster caster(v);
  const Vector3d hi = v.geometry.extent_mm() - 0.5 * v.geometry.spacing_mm;
  std::uniform_real_distribution<double> far(-80, 80), inside(0, 1);
  std::vector<Vector3d> from, to;
  std::normal_distribution<double> gauss;
  for (int n = 0; n < 1000; ++n) {  // random lines through the volume
    const Vector3d p = tracking::draw3(inside, rng).cwiseProduct(hi);
    const Vector3d d = tracking::draw3(gauss, rng).normalized();
    from.push_back(p - 100 * d);
    to.push_back(p + 100 * d);
  }
  for (int n = 0; n < 100; ++n) {  // random segments, many missing
    from.push_back(tracking::draw3(far, rng));
    to.push_back(tracking::draw3(far, rng));
  }
  for (int n = 0; n < 200; ++n) {  // starting or ending inside
    const Vector3d p = tracking::draw3(inside, rng).cwiseProduct(hi);
    from.push_back(p);
    to.push_back(tracking::draw3(far, rng));
    from.push_back(tracking::draw3(far, rng));
    to.push_back(p);
  }
  for (int ax = 0; ax < 3; ++ax) {  // along each axis, on a shared face, on lower and upper faces
    for (const double at : {2.0, 0.5, -0.5, hi[(ax + 1) % 3]}) {
      Vector3d p0(3.3, 4.4, 5.5), p1;
      p0[(ax + 1) % 3] = at * (at > 2.5 ? 1.0 : v.geometry.spacing_mm[(ax + 1) % 3]);
      p1 = p0;
      p0[ax] = -40;
      p1[ax] = 90;
      from.push_back(p0), to.push_back(p1);
      from.push_back(p1), to.push_back(p0);
    }
  }
  from.emplace_back(-1.5, -1.5, -1.5), to.emplace_back(30, 30, 30);  // through a corner
  from.emplace_back(3, 3, 3), to.emplace_back(3, 3, 3);              // zero length
  from.emplace_back(-20, 200, 3), to.emplace_back(20, 200, 3);       // misses
  from.emplace_back(std::nan(""), 2, 2), to.emplace_back(4, 2, 2);   // not a ray
  ASSERT_NE(from.size() % 16, 0u) << "the test wants a partial group";

  std::vector<double> batch(from.size()), avx2_batch(from.size()), scalar_batch(from.size());
  caster.siddon_batch(from, to, batch);
  caster.siddon_batch(from, to, avx2_batch, SiddonLanes::kAvx2);
  caster.siddon_batch(from, to, scalar_batch, SiddonLanes::kNone);
  int nonzero = 0;
  for (std::size_t i = 0; i < from.size(); ++i) {
    const double expected = caster.siddon(from[i], to[i]);
    nonzero += expected > 0;
    EXPECT_EQ(batch[i], expected) << "ray " << i;
    EXPECT_EQ(avx2_batch[i], expected) << "ray " << i;
    EXPECT_EQ(scalar_batch[i], expected) << "ray " << i;
  }
  EXPECT_GT(nonzero, 1000);
  if (!GridRayCaster::siddon_lanes_available()) GTEST_SKIP() << "no AVX-512 or AVX2: only the scalar path ran";
}

// Values inside a shell of zeros (a patient in air): every ray's integral is the brute-force sum
// over every voxel, the lanes give the scalar walk's bits, and a ray through the shell alone, or
// a volume of zeros, integrates to 0.
TEST(Siddon, ValuesInsideAShellOfZerosIntegrateAsTheBruteForceSum) {
  MuVolume v = uniform_box({30, 26, 14}, {1.1, 0.9, 2.5}, 0.0f);
  std::mt19937 rng(21);
  std::uniform_real_distribution<float> value(0.001f, 0.05f);
  const Eigen::Vector3i first(5, 7, 3), last(20, 18, 10);
  for (int k = first.z(); k <= last.z(); ++k)
    for (int j = first.y(); j <= last.y(); ++j)
      for (int i = first.x(); i <= last.x(); ++i)
        v.values[static_cast<std::size_t>(i + 30 * (j + 26 * k))] = value(rng);
  const GridRayCaster caster(v);
  const Vector3d s = v.geometry.spacing_mm;
  const Vector3d hi = v.geometry.extent_mm() - 0.5 * s;
  std::uniform_real_distribution<double> inside(0, 1);
  std::normal_distribution<double> gauss;
  std::vector<Vector3d> from, to, reference_shift;
  for (int n = 0; n < 600; ++n) {  // lines through the grid, and segments ending in the shell
    const Vector3d p = tracking::draw3(inside, rng).cwiseProduct(hi);
    const Vector3d d = tracking::draw3(gauss, rng).normalized();
    from.push_back(p - 100 * d);
    to.push_back(p + 100 * d);
    from.push_back(p);
    to.push_back(p + 100 * d);
  }
  reference_shift.assign(from.size(), Vector3d::Zero());
  // Along each axis, on the values' lower and upper faces and on a face between two of them. A ray on
  // a face belongs to the voxel above it: the brute force, whose boxes are closed, counts both
  // sides, so it takes these rays 1e-6 mm above the face.
  for (int ax = 0; ax < 3; ++ax) {
    const int across = (ax + 1) % 3;
    for (const double at : {first[across] - 0.5, last[across] + 0.5, first[across] + 2.5}) {
      Vector3d p0(12.1, 11.3, 16.2), p1;
      p0[across] = at * s[across];
      p1 = p0;
      p0[ax] = -40;
      p1[ax] = 90;
      from.push_back(p0), to.push_back(p1);
      from.push_back(p1), to.push_back(p0);
      Vector3d above = Vector3d::Zero();
      above[across] = 1e-6;
      reference_shift.insert(reference_shift.end(), 2, above);
    }
  }
  from.emplace_back(1, 1, 1), to.emplace_back(1, 30, 1);  // through the shell alone
  reference_shift.emplace_back(Vector3d::Zero());
  std::vector<double> batch(from.size()), scalar_batch(from.size());
  caster.siddon_batch(from, to, batch);
  caster.siddon_batch(from, to, scalar_batch, SiddonLanes::kNone);
  int nonzero = 0;
  for (std::size_t i = 0; i < from.size(); ++i) {
    const double expected = brute_force(v, from[i] + reference_shift[i], to[i] + reference_shift[i]);
    const double walked = caster.siddon(from[i], to[i]);
    nonzero += expected > 0;
    EXPECT_NEAR(walked, expected, 1e-9 * std::max(expected, 1.0)) << "ray " << i;
    EXPECT_EQ(batch[i], walked) << "ray " << i;
    EXPECT_EQ(scalar_batch[i], walked) << "ray " << i;
  }
  EXPECT_GT(nonzero, 400);
  EXPECT_EQ(caster.siddon(from.back(), to.back()), 0.0);

  const MuVolume zeros = uniform_box({9, 8, 7}, {1, 1, 1}, 0.0f);
  const GridRayCaster empty(zeros);
  std::vector<double> none(from.size(), -1.0);
  empty.siddon_batch(from, to, none);
  for (std::size_t i = 0; i < from.size(); ++i) {
    EXPECT_EQ(none[i], 0.0) << "ray " << i;
    EXPECT_EQ(empty.siddon(from[i], to[i]), 0.0) << "ray " << i;
  }
}

// A voxelised sphere and ellipsoid: Siddon equals the exact sum of per-voxel chords to 1e-5
// relative, and converges to the analytic chord of the smooth shape as voxels shrink.
class VoxelisedShape : public ::testing::TestWithParam<Vector3d> {};

MuVolume voxelise(const Vector3d& semi_axes_mm, double voxel_mm, float mu, Vector3d* centre) {
  const int n = static_cast<int>(std::ceil(2.2 * semi_axes_mm.maxCoeff() / voxel_mm));
  MuVolume v = uniform_box({n, n, n}, Vector3d::Constant(voxel_mm), 0.0f);
  *centre = Vector3d::Constant(0.5 * (n - 1) * voxel_mm);
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const Vector3d p = Vector3d(i, j, k) * voxel_mm - *centre;
        if (p.cwiseQuotient(semi_axes_mm).squaredNorm() <= 1.0) v.at(i, j, k) = mu;
      }
  return v;
}

double analytic_chord(const Vector3d& semi, const Vector3d& p0, const Vector3d& p1) {
  const Vector3d a = p0.cwiseQuotient(semi), d = (p1 - p0).cwiseQuotient(semi);
  const double qa = d.squaredNorm(), qb = 2 * a.dot(d), qc = a.squaredNorm() - 1;
  const double disc = qb * qb - 4 * qa * qc;
  if (disc <= 0) return 0;
  const double t0 = std::max(0.0, (-qb - std::sqrt(disc)) / (2 * qa));
  const double t1 = std::min(1.0, (-qb + std::sqrt(disc)) / (2 * qa));
  return t1 > t0 ? (t1 - t0) * (p1 - p0).norm() : 0;
}

TEST_P(VoxelisedShape, SiddonEqualsExactVoxelChords) {
  Vector3d centre;
  const MuVolume v = voxelise(GetParam(), 1.0, 0.025f, &centre);
  const GridRayCaster caster(v);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int n = 0; n < 40; ++n) {
    const Vector3d dir = tracking::draw3(u, rng).normalized();
    const Vector3d offset = 0.6 * GetParam().minCoeff() * tracking::draw3(u, rng);
    const Vector3d p0 = centre + offset - 100 * dir, p1 = centre + offset + 100 * dir;
    const double expected = brute_force(v, p0, p1);
    ASSERT_GT(expected, 0);
    EXPECT_NEAR(caster.siddon(p0, p1), expected, 1e-5 * expected) << n;
  }
}

TEST_P(VoxelisedShape, ConvergesToTheAnalyticChord) {
  double previous_error = 1e9;
  for (double voxel : {1.0, 0.5, 0.25}) {
    Vector3d centre;
    const MuVolume v = voxelise(GetParam(), voxel, 1.0f, &centre);
    const GridRayCaster caster(v);
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(-1, 1);
    double error = 0;
    for (int n = 0; n < 30; ++n) {
      const Vector3d dir = tracking::draw3(u, rng).normalized();
      const Vector3d offset = 0.5 * GetParam().minCoeff() * tracking::draw3(u, rng) / std::sqrt(3.0);
      const Vector3d p0 = offset - 100 * dir, p1 = offset + 100 * dir;
      const double exact = analytic_chord(GetParam(), p0, p1);
      error += std::abs(caster.siddon(centre + p0, centre + p1) - exact) / exact;
    }
    error /= 30;
    EXPECT_LT(error, previous_error) << "voxel " << voxel;
    // First-order convergence: the voxelised surface is off by up to half a voxel.
    EXPECT_LT(error, 0.03 * voxel) << "mean relative error at voxel " << voxel << " mm";
    previous_error = error;
  }
}

INSTANTIATE_TEST_SUITE_P(SphereAndEllipsoid, VoxelisedShape,
                         ::testing::Values(Vector3d(12, 12, 12), Vector3d(14, 9, 6)),
                         [](const auto& p) { return p.index == 0 ? "Sphere" : "Ellipsoid"; });

TEST(Trilinear, HomogeneousBoxMatchesSiddon) {
  const MuVolume box = uniform_box({12, 10, 8}, {1.0, 0.8, 2.0}, 0.03f);
  const GridRayCaster caster(box);
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-40, 40);
  for (int n = 0; n < 200; ++n) {
    const Vector3d p0 = tracking::draw3(u, rng);
    const Vector3d p1 = tracking::draw3(u, rng);
    const double s = caster.siddon(p0, p1);
    EXPECT_NEAR(caster.trilinear(p0, p1, 0.4), s, 1e-5 * std::max(s, 1e-3)) << n;
  }
}

TEST(Trilinear, ApproachesSiddonOnSmoothVolumes) {
  MuVolume v = uniform_box({24, 24, 24}, {1, 1, 1}, 0.0f);
  for (int k = 0; k < 24; ++k)
    for (int j = 0; j < 24; ++j)
      for (int i = 0; i < 24; ++i)
        v.at(i, j, k) = static_cast<float>(0.02 * (1 + std::sin(0.3 * i) * std::cos(0.2 * j + 0.1 * k)));
  const GridRayCaster caster(v);
  const Vector3d p0(-30, 5.3, 7.9), p1(60, 17.1, 14.2);
  const double s = caster.siddon(p0, p1);
  EXPECT_NEAR(caster.trilinear(p0, p1, 0.25), s, 0.01 * s);
}

}  // namespace
}  // namespace lftrack::tracking
