#include "lftrack/tracking/volume.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace lftrack::tracking {

Eigen::Affine3d VolumeGeometry::ct_from_index() const {
  Eigen::Affine3d t = Eigen::Affine3d::Identity();
  t.linear() = direction * spacing_mm.asDiagonal();
  t.translation() = origin_mm;
  return t;
}

Eigen::Affine3d VolumeGeometry::index_from_ct() const {
  return ct_from_index().inverse();
}

Eigen::Isometry3d VolumeGeometry::grid_from_ct() const {
  Eigen::Isometry3d ct_from_grid = Eigen::Isometry3d::Identity();
  ct_from_grid.linear() = direction;
  ct_from_grid.translation() = origin_mm;
  return ct_from_grid.inverse();
}

Eigen::Vector3d VolumeGeometry::centre_mm() const {
  const Eigen::Vector3d centre_index = (size.cast<double>() - Eigen::Vector3d::Ones()) * 0.5;
  return ct_from_index() * centre_index;
}

Status VolumeGeometry::validate() const {
  for (int a = 0; a < 3; ++a) {
    if (size[a] < 1 || size[a] > kMaxVoxelsPerAxis) {
      return out_of_range("volume size " + std::to_string(size[a]) + " along axis " + std::to_string(a) +
                          " is outside 1.." + std::to_string(kMaxVoxelsPerAxis));
    }
  }
  if (voxel_count() > kMaxVoxels) {
    return out_of_range("volume of " + std::to_string(voxel_count()) + " voxels exceeds the limit of " +
                        std::to_string(kMaxVoxels));
  }
  for (int a = 0; a < 3; ++a) {
    const double s = spacing_mm[a];
    if (!std::isfinite(s) || s < kMinSpacingMm || s > kMaxSpacingMm) {
      std::ostringstream m;
      m << "voxel spacing " << s << " mm along axis " << a << " is not a finite value in [" << kMinSpacingMm
        << ", " << kMaxSpacingMm << "] mm";
      return out_of_range(m.str());
    }
  }
  if (!origin_mm.allFinite()) return out_of_range("volume origin is not finite");
  if (origin_mm.cwiseAbs().maxCoeff() > kMaxOriginMm) {
    std::ostringstream m;
    m << "volume origin (" << origin_mm.x() << ", " << origin_mm.y() << ", " << origin_mm.z() << ") mm is more than "
      << kMaxOriginMm << " mm from the scanner's origin along an axis: a damaged position, not a patient";
    return out_of_range(m.str());
  }
  if (!direction.allFinite() ||
      !(direction.transpose() * direction).isApprox(Eigen::Matrix3d::Identity(), 1e-4)) {
    return unsupported("voxel axes are not orthonormal (sheared or scaled direction matrix)");
  }
  return {};
}

MuVolume block_averaged(const MuVolume& mu, const Eigen::Vector3i& factor) {
  const Eigen::Vector3i f = factor.cwiseMax(1).cwiseMin(64);
  const VolumeGeometry& g = mu.geometry;
  MuVolume out;
  out.geometry = g;
  for (int a = 0; a < 3; ++a) {
    out.geometry.size[a] = (g.size[a] + f[a] - 1) / f[a];
    out.geometry.spacing_mm[a] = g.spacing_mm[a] * f[a];
  }
  // The first new voxel's centre: the old grid's corner plus half a new voxel.
  const Eigen::Vector3d shift = 0.5 * (f.cast<double>() - Eigen::Vector3d::Ones()).cwiseProduct(g.spacing_mm);
  out.geometry.origin_mm = g.origin_mm + g.direction * shift;
  out.values.assign(std::size_t(out.geometry.voxel_count()), 0.f);
  const float share = 1.f / float(f.x() * f.y() * f.z());
  for (int k = 0; k < g.size.z(); ++k)
    for (int j = 0; j < g.size.y(); ++j)
      for (int i = 0; i < g.size.x(); ++i) out.at(i / f.x(), j / f.y(), k / f.z()) += share * mu.at(i, j, k);
  return out;
}

MuVolume to_attenuation(const CtVolume& ct, double mu_water_per_mm) {
  MuVolume mu;
  mu.geometry = ct.geometry;
  mu.values.resize(ct.values.size());
  // In double, so that -1000 HU is exactly 0.
  std::transform(ct.values.begin(), ct.values.end(), mu.values.begin(), [&](float hu) {
    return std::isfinite(hu)
               ? static_cast<float>(std::max(0.0, mu_water_per_mm * (1.0 + double(hu) / 1000.0)))
               : 0.0f;
  });
  return mu;
}

Status check_attenuation_volume(const MuVolume& mu) {
  LFTRACK_RETURN_IF_ERROR(mu.geometry.validate());
  if (mu.values.size() != static_cast<std::size_t>(mu.geometry.voxel_count()))
    return invalid_argument("volume has " + std::to_string(mu.values.size()) + " values for " +
                            std::to_string(mu.geometry.voxel_count()) + " voxels");
  std::size_t bad = 0, first = 0;
  for (std::size_t i = 0; i < mu.values.size(); ++i) {
    const float v = mu.values[i];
    if (!(v >= 0.0f) || !std::isfinite(v)) {
      if (bad++ == 0) first = i;
    }
  }
  if (bad > 0)
    return invalid_argument("attenuation volume has " + std::to_string(bad) +
                            " value(s) that are negative, NaN or infinite (first at index " +
                            std::to_string(first) + ")");
  return {};
}

std::string describe(const VolumeGeometry& g) {
  std::ostringstream s;
  s.precision(4);
  s << g.size.x() << " x " << g.size.y() << " x " << g.size.z() << " voxels of " << g.spacing_mm.x() << " x "
    << g.spacing_mm.y() << " x " << g.spacing_mm.z() << " mm, origin (" << g.origin_mm.x() << ", "
    << g.origin_mm.y() << ", " << g.origin_mm.z() << ") mm";
  return s.str();
}

}  // namespace lftrack::tracking
