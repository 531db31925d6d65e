#pragma once
// A CT volume on a regular grid, placed in the CT frame (patient LPS, millimetres).
//
// Voxel (i, j, k) has its centre at  x_ct = origin_mm + direction * (spacing_mm .* (i, j, k)).
// Columns of `direction` are the unit vectors of the i, j, k axes in the CT frame; they are
// orthonormal (readers reject sheared grids). Values are stored with i fastest:
// index = i + size.x * (j + size.y * k).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {

struct VolumeGeometry {
  Eigen::Vector3i size = Eigen::Vector3i::Zero();           // voxels along i, j, k
  Eigen::Vector3d spacing_mm = Eigen::Vector3d::Ones();     // voxel pitch along i, j, k
  Eigen::Vector3d origin_mm = Eigen::Vector3d::Zero();      // centre of voxel (0,0,0), CT frame
  Eigen::Matrix3d direction = Eigen::Matrix3d::Identity();  // columns: i, j, k axes in CT frame

  std::int64_t voxel_count() const { return std::int64_t{size.x()} * size.y() * size.z(); }
  // Continuous voxel index -> CT frame (mm). Integer indices are voxel centres.
  Eigen::Affine3d ct_from_index() const;
  Eigen::Affine3d index_from_ct() const;
  // Rigid map from the CT frame to the grid frame: axes along i, j, k, origin at voxel (0,0,0)'s
  // centre, millimetres. Voxel (i,j,k) spans [(i-0.5) s_i, (i+0.5) s_i] x ... in this frame.
  Eigen::Isometry3d grid_from_ct() const;
  // Centre of the volume's bounding box in the CT frame.
  Eigen::Vector3d centre_mm() const;
  // Physical extent along i, j, k (size * spacing), mm.
  Eigen::Vector3d extent_mm() const { return size.cast<double>().cwiseProduct(spacing_mm); }

  // Checks sizes (1..kMaxVoxelsPerAxis, total <= kMaxVoxels), spacing (finite, in
  // [kMinSpacingMm, kMaxSpacingMm]), origin (finite, within kMaxOriginMm) and direction (orthonormal to 1e-4).
  Status validate() const;

  static constexpr int kMaxVoxelsPerAxis = 8192;
  static constexpr std::int64_t kMaxVoxels = std::int64_t{1} << 31;  // 8 GiB of float
  static constexpr double kMinSpacingMm = 1e-3;
  static constexpr double kMaxSpacingMm = 100.0;
  static constexpr double kMaxOriginMm = 10000;  // 10 m: table positions stay within a few metres
};

// Unit tags so that HU volumes and attenuation volumes cannot be mixed up.
struct HounsfieldUnits {};
struct AttenuationPerMm {};

template <class Unit>
struct ScalarVolume {
  VolumeGeometry geometry;
  std::vector<float> values;  // geometry.voxel_count() entries, i fastest

  float at(int i, int j, int k) const {
    return values[static_cast<std::size_t>(i + std::int64_t{geometry.size.x()} *
                                                   (j + std::int64_t{geometry.size.y()} * k))];
  }
  float& at(int i, int j, int k) {
    return values[static_cast<std::size_t>(i + std::int64_t{geometry.size.x()} *
                                                   (j + std::int64_t{geometry.size.y()} * k))];
  }
};

using CtVolume = ScalarVolume<HounsfieldUnits>;   // Hounsfield units
using MuVolume = ScalarVolume<AttenuationPerMm>;  // linear attenuation, 1/mm

// Attenuation of water at the effective energy of a kV imaging beam (about 70 keV), 1/mm.
inline constexpr double kDefaultMuWaterPerMm = 0.0193;

// mu = mu_water * (1 + HU / 1000), clamped at 0 (DESIGN.md, "Attenuation"). A non-finite HU (the
// readers refuse them; this is the last line of defence) gives mu = 0, so no NaN reaches a DRR.
MuVolume to_attenuation(const CtVolume& ct, double mu_water_per_mm = kDefaultMuWaterPerMm);

// The volume on a grid `factor` times coarser along each axis (each factor 1..64): each new voxel
// is the mean of the factor.x x factor.y x factor.z voxels it covers, voxels beyond the last
// counting as air (0), so that line integrals through it keep their value on average. The new
// grid starts at the same corner as the old; for a ray caster drawing a coarse image, where the
// volume's own voxels are much finer than the image's pixels.
MuVolume block_averaged(const MuVolume& mu, const Eigen::Vector3i& factor);

// Checks what every renderer and light-field build needs of an attenuation volume: a valid
// geometry, as many values as voxels, and every value finite and >= 0.
Status check_attenuation_volume(const MuVolume& mu);

// Summary line for logs: size, spacing, origin, value range.
std::string describe(const VolumeGeometry& geometry);

}  // namespace lftrack::tracking
