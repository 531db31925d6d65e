#pragma once
// One X-ray view: a point source and a flat detector, in the room frame (mm).
//
// Pixel (row, col) has its centre at  pixel00_mm + col * pitch_col_mm * col_axis
//                                                + row * pitch_row_mm * row_axis.
// Row 0 is the top row of the image; col_axis points along a row (columns increasing), row_axis
// down the image (rows increasing). The two axes are orthonormal. Pixel coordinates are
// continuous: (r, c) = (0, 0) is the centre of the first pixel, its edges are at -0.5 and +0.5.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <optional>
#include <string>

#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {

using Matrix34d = Eigen::Matrix<double, 3, 4>;

struct XrayView {
  std::string name;
  Eigen::Vector3d source_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d pixel00_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d col_axis = Eigen::Vector3d::UnitX();
  Eigen::Vector3d row_axis = Eigen::Vector3d::UnitY();
  double pitch_col_mm = 1.0;
  double pitch_row_mm = 1.0;
  int rows = 0;
  int cols = 0;

  Eigen::Vector3d pixel_centre_mm(double row, double col) const {
    return pixel00_mm + col * pitch_col_mm * col_axis + row * pitch_row_mm * row_axis;
  }
  // Unit normal of the detector, pointing from the detector towards the source's side.
  Eigen::Vector3d detector_normal() const;
  // Foot of the perpendicular from the source onto the detector plane (the principal point).
  Eigen::Vector3d principal_point_mm() const;
  double source_to_detector_mm() const;
  // Centre of the detector (between its middle pixels), and moving the detector so its centre
  // lies at `centre_mm` (axes and pitch unchanged).
  Eigen::Vector3d detector_centre_mm() const;
  void set_detector_centre(const Eigen::Vector3d& centre_mm);
  // Columns: col_axis, row_axis, col_axis x row_axis (the detector's orientation).
  Eigen::Matrix3d detector_axes() const;

  // 3x4 matrix P with  w * (col, row, 1)^T = P * (x, y, z, 1)^T  for a point in the frame this
  // view is expressed in; w > 0 for points in front of the source (towards the detector).
  Matrix34d projection() const;
  // Pixel coordinates (col, row) of a point, or nothing if it is at or behind the source plane.
  std::optional<Eigen::Vector2d> project(const Eigen::Vector3d& point_mm) const;

  // The same view expressed in another frame: every point and axis mapped by `T_new_from_old`.
  XrayView transformed(const Eigen::Isometry3d& T_new_from_old) const;

  // The part of this detector under `window`, resampled to rows x cols pixels that cover the
  // same area (pitch scaled accordingly): a cropped, binned or super-sampled detector.
  XrayView resampled(int window_row0, int window_col0, int window_rows, int window_cols, int rows,
                     int cols) const;

  // Finite values, positive pitch, 1..16384 rows and cols, orthonormal axes, source off the
  // detector plane on the side the normal points to.
  Status validate() const;

  // A view built the way isocentric systems are specified: the source at `source_to_iso_mm`
  // from the isocentre along `source_direction` (a unit vector from the isocentre towards the
  // source), the detector perpendicular to that axis at `source_to_detector_mm` from the source
  // and centred on it, with its top edge towards `up` (projected onto the detector plane).
  static Result<XrayView> isocentric(std::string name, const Eigen::Vector3d& isocentre_mm,
                                     const Eigen::Vector3d& source_direction, const Eigen::Vector3d& up,
                                     double source_to_iso_mm, double source_to_detector_mm, int rows,
                                     int cols, double pitch_mm);
};

}  // namespace lftrack::tracking
