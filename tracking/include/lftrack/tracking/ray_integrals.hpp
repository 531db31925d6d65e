#pragma once
// Line integrals of attenuation through a volume: the numerical core under every ray-cast DRR
// and under the light-field precomputation.
//
// Rays are given in the grid frame (VolumeGeometry::grid_from_ct): axes along i, j, k, mm, origin
// at the centre of voxel (0,0,0); voxel (i,j,k) is the box [(i-0.5)s_i, (i+0.5)s_i) x ... .
// Boxes are half-open: a ray running exactly along a shared face belongs to the voxel on the
// upper side, a ray along the volume's upper face misses it. Results are mu * mm (unitless).
// All functions are const, thread-safe and allocation-free.

#include <Eigen/Core>
#include <span>

#include "lftrack/tracking/volume.hpp"

namespace lftrack::tracking {

namespace detail {
struct SiddonWalk;
}

// Which walk GridRayCaster::siddon_batch takes: the widest vector lanes this CPU has (AVX-512,
// else AVX2), AVX2 lanes even where AVX-512 is present (so that tests check both kernels on one
// host), or one ray at a time.
enum class SiddonLanes { kBest, kAvx2, kNone };

class GridRayCaster {
 public:
  // Keeps a reference to `volume`, which must outlive the caster.
  explicit GridRayCaster(const MuVolume& volume);

  // Exact radiological path (Siddon-Jacobs): sum of mu times the length of the segment
  // [from, to] inside each voxel. Parts of the segment outside the volume contribute 0.
  double siddon(const Eigen::Vector3d& from_grid_mm, const Eigen::Vector3d& to_grid_mm) const;

  // siddon() for many rays: integrals[i] = siddon(from[i], to[i]), bit for bit for a volume of
  // finite values. On a CPU with AVX-512 or AVX2 it walks sixteen rays at once (AVX-512: about
  // 2-3x the scalar rate on the light-field precompute; AVX2 on Zen 3: about 1.5-2x); elsewhere,
  // or where `lanes` asks for lanes this CPU lacks, or kNone, one at a time. The spans must have
  // equal sizes.
  void siddon_batch(std::span<const Eigen::Vector3d> from_grid_mm,
                    std::span<const Eigen::Vector3d> to_grid_mm, std::span<double> integrals,
                    SiddonLanes lanes = SiddonLanes::kBest) const;
  // True if siddon_batch walks vector lanes of this kind on this CPU (kNone: false).
  static bool siddon_lanes_available(SiddonLanes lanes = SiddonLanes::kBest);

  // Fixed-step sampling of the trilinearly interpolated volume along [from, to]: the clipped
  // segment is cut into ceil(length / step_mm) equal parts, each sampled at its midpoint.
  // Inside the half-voxel border the edge voxel's value is used (no fade to zero), so a
  // homogeneous volume gives the same chord as siddon().
  double trilinear(const Eigen::Vector3d& from_grid_mm, const Eigen::Vector3d& to_grid_mm,
                   double step_mm) const;

  // Clips the segment from + a (to - from), a in [0,1], to the volume's box. Returns false if
  // it misses (including grazing the upper faces), else the entry and exit parameters.
  bool clip(const Eigen::Vector3d& from_grid_mm, const Eigen::Vector3d& to_grid_mm, double* a_enter,
            double* a_exit) const;

  const VolumeGeometry& geometry() const { return volume_.geometry; }

 private:
  // Where the Siddon walk of [from, to] starts (tracking/src/siddon_walk.hpp); false if the
  // segment misses the volume.
  bool start_walk(const Eigen::Vector3d& from, const Eigen::Vector3d& to, detail::SiddonWalk* walk) const;

  const MuVolume& volume_;
  Eigen::Vector3d lower_mm_;  // lower corner of the box, grid frame
  Eigen::Vector3d upper_mm_;  // upper corner of the box, grid frame
};

}  // namespace lftrack::tracking
