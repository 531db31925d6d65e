#include "lftrack/tracking/xray_view.hpp"

#include <cmath>
#include <sstream>

namespace lftrack::tracking {

Eigen::Vector3d XrayView::detector_normal() const {
  Eigen::Vector3d n = col_axis.cross(row_axis).normalized();
  if (n.dot(source_mm - pixel00_mm) < 0) n = -n;
  return n;
}

Eigen::Vector3d XrayView::principal_point_mm() const {
  const Eigen::Vector3d n = detector_normal();
  return source_mm - n * n.dot(source_mm - pixel00_mm);
}

double XrayView::source_to_detector_mm() const {
  return std::abs(detector_normal().dot(source_mm - pixel00_mm));
}

Eigen::Vector3d XrayView::detector_centre_mm() const {
  return pixel_centre_mm(0.5 * (rows - 1), 0.5 * (cols - 1));
}

void XrayView::set_detector_centre(const Eigen::Vector3d& centre_mm) {
  pixel00_mm =
      centre_mm - 0.5 * (cols - 1) * pitch_col_mm * col_axis - 0.5 * (rows - 1) * pitch_row_mm * row_axis;
}

Eigen::Matrix3d XrayView::detector_axes() const {
  Eigen::Matrix3d axes;
  axes << col_axis, row_axis, col_axis.cross(row_axis);
  return axes;
}

Matrix34d XrayView::projection() const {
  // A point X projects to Q = S + lambda (X - S) on the plane n.(Q - O) = 0, with
  // lambda = n.(O - S) / n.(X - S). Then col = a.(Q - O) / pitch_col, row = b.(Q - O) / pitch_row.
  // Multiplying through by w = n.(S - X) / n.(S - O)... gives rows linear in X, assembled below.
  const Eigen::Vector3d& s = source_mm;
  const Eigen::Vector3d& o = pixel00_mm;
  const Eigen::Vector3d n = detector_normal();
  const double h = n.dot(s - o);  // source height above the detector plane, > 0
  // Q - O = (S - O) + lambda (X - S), lambda = h / n.(S - X).
  // Let w = n.(S - X) / h (positive in front of the source). Then
  // w * a.(Q - O) = w a.(S - O) + a.(X - S) = [a - (a.(S-O)/h) n].X + const.
  Matrix34d p;
  auto fill_row = [&](int r, const Eigen::Vector3d& axis, double pitch) {
    const double k = axis.dot(s - o) / h;
    const Eigen::Vector3d lin = (axis - k * n) / pitch;
    const double c = (k * n.dot(s) - axis.dot(s)) / pitch;
    p.block<1, 3>(r, 0) = lin.transpose();
    p(r, 3) = c;
  };
  fill_row(0, col_axis, pitch_col_mm);
  fill_row(1, row_axis, pitch_row_mm);
  p.block<1, 3>(2, 0) = (-n / h).transpose();
  p(2, 3) = n.dot(s) / h;
  return p;
}

std::optional<Eigen::Vector2d> XrayView::project(const Eigen::Vector3d& point_mm) const {
  const Eigen::Vector3d h = projection() * point_mm.homogeneous();
  if (!(h.z() > 1e-12)) return std::nullopt;
  return Eigen::Vector2d(h.x() / h.z(), h.y() / h.z());
}

XrayView XrayView::transformed(const Eigen::Isometry3d& T_new_from_old) const {
  XrayView v = *this;
  v.source_mm = T_new_from_old * source_mm;
  v.pixel00_mm = T_new_from_old * pixel00_mm;
  v.col_axis = T_new_from_old.linear() * col_axis;
  v.row_axis = T_new_from_old.linear() * row_axis;
  return v;
}

XrayView XrayView::resampled(int window_row0, int window_col0, int window_rows, int window_cols, int new_rows,
                             int new_cols) const {
  XrayView v = *this;
  v.rows = new_rows;
  v.cols = new_cols;
  v.pitch_row_mm = pitch_row_mm * window_rows / new_rows;
  v.pitch_col_mm = pitch_col_mm * window_cols / new_cols;
  // The window's outer corner (edge of its first pixel), then half a new pixel inwards.
  const Eigen::Vector3d corner = pixel_centre_mm(window_row0 - 0.5, window_col0 - 0.5);
  v.pixel00_mm = corner + 0.5 * v.pitch_row_mm * row_axis + 0.5 * v.pitch_col_mm * col_axis;
  return v;
}

Status XrayView::validate() const {
  const std::string who = "view '" + name + "': ";
  if (!source_mm.allFinite() || !pixel00_mm.allFinite() || !col_axis.allFinite() || !row_axis.allFinite() ||
      !std::isfinite(pitch_col_mm) || !std::isfinite(pitch_row_mm)) {
    return invalid_argument(who + "geometry has a non-finite value");
  }
  if (!(pitch_col_mm > 0) || !(pitch_row_mm > 0) || pitch_col_mm > 100 || pitch_row_mm > 100) {
    return out_of_range(who + "pixel pitch must be in (0, 100] mm");
  }
  if (rows < 1 || cols < 1 || rows > 16384 || cols > 16384) {
    return out_of_range(who + "detector must have 1..16384 rows and columns, has " + std::to_string(rows) +
                        " x " + std::to_string(cols));
  }
  if (std::abs(col_axis.norm() - 1) > 1e-6 || std::abs(row_axis.norm() - 1) > 1e-6 ||
      std::abs(col_axis.dot(row_axis)) > 1e-6) {
    return invalid_argument(who + "detector row and column axes must be orthonormal");
  }
  if (source_to_detector_mm() < 1.0) {
    return invalid_argument(who + "source lies on (within 1 mm of) the detector plane");
  }
  return {};
}

Result<XrayView> XrayView::isocentric(std::string name, const Eigen::Vector3d& isocentre_mm,
                                      const Eigen::Vector3d& source_direction, const Eigen::Vector3d& up,
                                      double source_to_iso_mm, double source_to_detector_mm, int rows,
                                      int cols, double pitch_mm) {
  if (!(source_direction.norm() > 1e-9) || !source_direction.allFinite()) {
    return invalid_argument("view '" + name + "': source direction is zero or not finite");
  }
  if (!(source_to_iso_mm > 0) || !(source_to_detector_mm > source_to_iso_mm)) {
    return invalid_argument("view '" + name +
                            "': need 0 < source-to-isocentre < source-to-detector distance");
  }
  const Eigen::Vector3d beam = -source_direction.normalized();  // source -> detector
  Eigen::Vector3d up_on_plane = up - up.dot(beam) * beam;
  if (!(up_on_plane.norm() > 1e-6)) {
    return invalid_argument("view '" + name + "': 'up' is parallel to the beam axis");
  }
  up_on_plane.normalize();
  XrayView v;
  v.name = std::move(name);
  v.source_mm = isocentre_mm - beam * source_to_iso_mm;
  v.row_axis = -up_on_plane;
  // Columns increase to the right as seen looking from the source through the patient at the
  // detector: right = beam x up = row_axis x beam.
  v.col_axis = v.row_axis.cross(beam).normalized();
  v.pitch_col_mm = v.pitch_row_mm = pitch_mm;
  v.rows = rows;
  v.cols = cols;
  const Eigen::Vector3d centre = v.source_mm + beam * source_to_detector_mm;
  v.pixel00_mm = centre - 0.5 * (cols - 1) * pitch_mm * v.col_axis - 0.5 * (rows - 1) * pitch_mm * v.row_axis;
  if (Status s = v.validate(); !s.ok()) return s;
  return v;
}

}  // namespace lftrack::tracking
