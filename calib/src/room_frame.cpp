#include "lftrack/calib/room_frame.hpp"

#include <algorithm>
#include <cmath>

namespace lftrack::calib {

Result<RoomFrame> room_frame_from_views(const tracking::XrayView& a, const tracking::XrayView& b) {
  LFTRACK_RETURN_IF_ERROR(a.validate());
  LFTRACK_RETURN_IF_ERROR(b.validate());
  // Central rays: source -> detector centre.
  const Eigen::Vector3d da = (a.detector_centre_mm() - a.source_mm).normalized();
  const Eigen::Vector3d db = (b.detector_centre_mm() - b.source_mm).normalized();
  const double angle = std::acos(std::clamp(da.dot(db), -1.0, 1.0));
  const double kDeg = 180.0 / 3.14159265358979323846;
  if (angle * kDeg < 10 || angle * kDeg > 170) {
    return invalid_argument("room frame: the two views' central rays are within 10 degrees of parallel (" +
                            std::to_string(angle * kDeg) + " degrees apart)");
  }
  // Closest points a.source + s da and b.source + t db.
  const Eigen::Vector3d w = a.source_mm - b.source_mm;
  const double c = da.dot(db), denom = 1 - c * c;
  const double s = (c * db.dot(w) - da.dot(w)) / denom;
  const double t = (db.dot(w) - c * da.dot(w)) / denom;
  const Eigen::Vector3d on_a = a.source_mm + s * da, on_b = b.source_mm + t * db;
  const Eigen::Vector3d iso = 0.5 * (on_a + on_b);
  const Eigen::Vector3d sa = (a.source_mm - iso).normalized(), sb = (b.source_mm - iso).normalized();
  const Eigen::Vector3d z = sb.cross(sa).normalized();
  Eigen::Vector3d y = -(sa + sb);
  y = (y - y.dot(z) * z).normalized();
  const Eigen::Vector3d x = y.cross(z);
  Eigen::Matrix3d room_from_views;
  room_from_views.row(0) = x.transpose();
  room_from_views.row(1) = y.transpose();
  room_from_views.row(2) = z.transpose();
  RoomFrame out;
  out.T_room_from_views.linear() = room_from_views;
  out.T_room_from_views.translation() = -room_from_views * iso;
  out.central_ray_gap_mm = (on_a - on_b).norm();
  out.angle_between_views_deg = angle * kDeg;
  return out;
}

}  // namespace lftrack::calib
