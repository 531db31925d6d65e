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
  if (!direction.allFinite() ||
      !(direction.transpose() * direction).isApprox(Eigen::Matrix3d::Identity(), 1e-4)) {
    return unsupported("voxel axes are not orthonormal (sheared or scaled direction matrix)");
  }
  return {};
}

MuVolume to_attenuation(const CtVolume& ct, double mu_water_per_mm) {
  MuVolume mu;
  mu.geometry = ct.geometry;
  mu.values.resize(ct.values.size());
  const float scale = static_cast<float>(mu_water_per_mm / 1000.0);
  const float offset = static_cast<float>(mu_water_per_mm);
  std::transform(ct.values.begin(), ct.values.end(), mu.values.begin(),
                 [&](float hu) { return std::max(0.0f, offset + scale * hu); });
  return mu;
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
