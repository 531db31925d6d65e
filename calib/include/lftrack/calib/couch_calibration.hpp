#pragma once
// The couch in the room (issue 8): its translation axes and rotation centre in the room frame,
// from known couch moves and the anatomy's (or a phantom's) measured motion after each one.
//
// The couch's frame: origin at its rotation centre, axes along its translation axes. A couch
// position q = (t [mm], omega [rad]) in its own terms moves its top by
//     E(q) = Translation(t) * exp(omega)                              (couch frame)
// and, with the couch mounted at X = T_room_from_couch, moves what lies on it in the room by
//     M(q) = X * E(q) * X^-1.
// With anatomy poses T_0 (at q = 0) and T_i (at q_i) measured in the room, A_i = T_i T_0^-1 and
// B_i = E(q_i) satisfy A_i X = X B_i (hand-eye). The solver initialises X in closed form (the
// rotation from the moves' translation directions and rotation axes by SVD, the centre from the
// rotating moves by linear least squares), then refines it with Ceres: residual = where
// M(q_i) puts points of a box at the registration origin minus where A_i puts them (mm), with a
// Huber loss. Needs pure translations along at least two directions, or rotations about two
// axes, and (for the centre) rotations about at least two axes.
//
// An ideal couch (axes = room axes, rotating about the registration origin c) is
// X = Translation(c); then M(q) is exactly tracking::apply_delta's motion of delta q about c.

#include <Eigen/Geometry>
#include <vector>

#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::calib {

// E(q): the couch-frame motion of couch position q.
Eigen::Isometry3d couch_motion(const tracking::Vector6d& q);
// The room motion of couch position q for a couch mounted at T_room_from_couch.
Eigen::Isometry3d room_motion_of_couch(const Eigen::Isometry3d& T_room_from_couch,
                                       const tracking::Vector6d& q);
// The couch position change that moves the room by `room_motion` (its inverse map):
// E(q) = X^-1 M X, q = (translation, rotation_log).
tracking::Vector6d couch_move_for(const Eigen::Isometry3d& T_room_from_couch,
                                  const Eigen::Isometry3d& room_motion);

struct CouchObservation {
  tracking::Vector6d couch_position = tracking::Vector6d::Zero();  // q_i, couch terms (mm, rad), from zero
  tracking::Pose T_room_from_object = tracking::Pose::Identity();  // measured after the move
};

struct CouchCalibration {
  Eigen::Isometry3d T_room_from_couch = Eigen::Isometry3d::Identity();
  double rms_mm = 0;                // RMS of the box points' residuals over all moves
  std::vector<double> move_rms_mm;  // per move
  Eigen::Vector3d rotation_sd_deg = Eigen::Vector3d::Zero();  // 1 sigma, about room axes
  Eigen::Vector3d centre_sd_mm = Eigen::Vector3d::Zero();     // of the rotation centre
  bool centre_determined = false;  // false: no rotating moves; the centre was kept at `centre_guess`
};

// `zero`: the object's pose at couch position 0; `moves`: at least 3 observations.
// `box_centre_room_mm` and `box_mm`: where the residual's 8 points lie (the registration origin
// and the TRE box). `centre_guess_room_mm`: the rotation centre if no move rotates.
Result<CouchCalibration> solve_couch_calibration(const tracking::Pose& zero,
                                                 const std::vector<CouchObservation>& moves,
                                                 const Eigen::Vector3d& box_centre_room_mm, double box_mm,
                                                 const Eigen::Vector3d& centre_guess_room_mm);

}  // namespace lftrack::calib
