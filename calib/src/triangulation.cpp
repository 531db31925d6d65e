#include "lftrack/calib/triangulation.hpp"

#include <Eigen/SVD>
#include <cmath>

namespace lftrack::calib {

Result<Triangulated> triangulate(const tracking::XrayView& view_a, const Eigen::Vector2d& pixel_a,
                                 const tracking::XrayView& view_b, const Eigen::Vector2d& pixel_b) {
  if (!pixel_a.allFinite() || !pixel_b.allFinite()) return invalid_argument("pixel is not finite");
  LFTRACK_RETURN_IF_ERROR(view_a.validate());
  LFTRACK_RETURN_IF_ERROR(view_b.validate());
  const Eigen::Vector3d p = view_a.source_mm;
  const Eigen::Vector3d q = view_b.source_mm;
  const Eigen::Vector3d u = (view_a.pixel_centre_mm(pixel_a.y(), pixel_a.x()) - p).normalized();
  const Eigen::Vector3d v = (view_b.pixel_centre_mm(pixel_b.y(), pixel_b.x()) - q).normalized();
  // Closest points p + s u and q + t v: minimise |p + s u - q - t v|^2.
  const Eigen::Vector3d w = p - q;
  const double b = u.dot(v);
  const double denom = 1.0 - b * b;
  if (denom < 1e-10) return invalid_argument("the two rays are parallel; cannot triangulate");
  const double d = u.dot(w), e = v.dot(w);
  const double s = (b * e - d) / denom;
  const double t = (e - b * d) / denom;
  const Eigen::Vector3d on_a = p + s * u;
  const Eigen::Vector3d on_b = q + t * v;
  return Triangulated{0.5 * (on_a + on_b), (on_a - on_b).norm()};
}

Result<RigidFit> fit_rigid(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to) {
  if (from.size() != to.size()) return invalid_argument("point sets differ in size");
  if (from.size() < 3) return invalid_argument("a rigid fit needs at least 3 point pairs");
  const double n = static_cast<double>(from.size());
  Eigen::Vector3d cf = Eigen::Vector3d::Zero(), ct = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < from.size(); ++i) {
    if (!from[i].allFinite() || !to[i].allFinite()) return invalid_argument("a point is not finite");
    cf += from[i];
    ct += to[i];
  }
  cf /= n;
  ct /= n;
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < from.size(); ++i) h += (from[i] - cf) * (to[i] - ct).transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Vector3d sv = svd.singularValues();
  if (sv(1) < 1e-9 * std::max(1.0, sv(0))) {
    return invalid_argument("points are collinear or coincident; the rotation is undetermined");
  }
  Eigen::Matrix3d correction = Eigen::Matrix3d::Identity();
  correction(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
  RigidFit fit;
  fit.T_to_from.linear() = svd.matrixV() * correction * svd.matrixU().transpose();
  fit.T_to_from.translation() = ct - fit.T_to_from.linear() * cf;
  double se = 0;
  for (std::size_t i = 0; i < from.size(); ++i) se += (fit.T_to_from * from[i] - to[i]).squaredNorm();
  fit.fre_rms_mm = std::sqrt(se / n);
  return fit;
}

}  // namespace lftrack::calib
