#include "lftrack/tracking/target_error.hpp"

#include <algorithm>
#include <cmath>

namespace lftrack::tracking {

Tre target_registration_error(const Pose& T, const Pose& gold, const VolumeGeometry& grid, const TreBox& box) {
  // The error at x is D x + d with D = R - R_gold, d = t - t_gold: affine in x, so only the sum
  // over the grid points needs a loop.
  const Eigen::Matrix3d D = T.linear() - gold.linear();
  const Eigen::Vector3d d = T.translation() - gold.translation();
  const Eigen::Affine3d index_from_ct = grid.index_from_ct();
  const Eigen::Affine3d ct_from_index = grid.ct_from_index();
  const double half = 0.5 * std::max(box.edge_mm, 0.0);
  Eigen::Vector3d lo_index = Eigen::Vector3d::Constant(1e300), hi_index = Eigen::Vector3d::Constant(-1e300);
  for (int corner = 0; corner < 8; ++corner) {
    const Eigen::Vector3d s((corner & 1) ? half : -half, (corner & 2) ? half : -half, (corner & 4) ? half : -half);
    const Eigen::Vector3d idx = index_from_ct * (box.centre_ct_mm + s);
    lo_index = lo_index.cwiseMin(idx);
    hi_index = hi_index.cwiseMax(idx);
  }
  Tre tre;
  double sum = 0;
  const Eigen::Matrix3d axes = grid.direction;
  for (int k = int(std::ceil(lo_index.z() - 1e-9)); k <= int(std::floor(hi_index.z() + 1e-9)); ++k) {
    for (int j = int(std::ceil(lo_index.y() - 1e-9)); j <= int(std::floor(hi_index.y() + 1e-9)); ++j) {
      for (int i = int(std::ceil(lo_index.x() - 1e-9)); i <= int(std::floor(hi_index.x() + 1e-9)); ++i) {
        const Eigen::Vector3d x = ct_from_index * Eigen::Vector3d(i, j, k);
        // Inside the box in the grid's own axes (the box is aligned with them).
        const Eigen::Vector3d local = axes.transpose() * (x - box.centre_ct_mm);
        if (local.cwiseAbs().maxCoeff() > half + 1e-9) continue;
        const double e = (D * x + d).norm();
        sum += e;
        tre.max_mm = std::max(tre.max_mm, e);
        ++tre.points;
      }
    }
  }
  if (tre.points == 0) {
    const double e = (D * box.centre_ct_mm + d).norm();
    return {e, e, 1};
  }
  tre.mean_mm = sum / tre.points;
  return tre;
}

}  // namespace lftrack::tracking
