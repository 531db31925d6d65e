#pragma once
// Point geometry shared by calibration and the hybrid similarity (PAPERS.md, paper 2):
// two-view triangulation and the least-squares rigid fit of point sets.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::calib {

struct Triangulated {
  Eigen::Vector3d point_mm;  // midpoint of the shortest segment between the two rays
  double gap_mm = 0;         // length of that segment: how far the rays miss each other
};

// Back-projects pixel (col, row) of each view and returns the midpoint of the shortest segment
// between the two rays. Both views must be in the same frame. Fails for (near-)parallel rays.
Result<Triangulated> triangulate(const tracking::XrayView& view_a, const Eigen::Vector2d& pixel_a,
                                 const tracking::XrayView& view_b, const Eigen::Vector2d& pixel_b);

struct RigidFit {
  Eigen::Isometry3d T_to_from = Eigen::Isometry3d::Identity();  // maps `from` points onto `to`
  double fre_rms_mm = 0;  // fiducial registration error: RMS residual after the fit
};

// Least-squares rigid transform (rotation + translation, no scale) with to ~ T * from
// (Arun/Umeyama by SVD). A reflection is never returned: if the best orthogonal fit is a
// reflection, the nearest proper rotation is used. Needs >= 3 non-collinear pairs.
Result<RigidFit> fit_rigid(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to);

}  // namespace lftrack::calib
