#pragma once
// Poses and the 6-vector the optimizer moves (DESIGN.md, "Frames, units, conventions").
//
// A pose is T_room_from_ct: it maps CT-frame points (mm) to room-frame points (mm).
// A PoseDelta is (t [mm], omega [rad]) applied about the registration origin c (room frame):
//     T = Translation(t + c) * exp(omega) * Translation(-c) * T0
// where exp(omega) is the rotation by |omega| about omega / |omega|.
//
// Euler angles exist only for display and for people typing poses. The one convention used
// everywhere: R = Rz(yaw) * Ry(pitch) * Rx(roll), rotations about the fixed room axes x, y, z
// applied in that order (roll first). At pitch = +-90 degrees roll and yaw share one axis; the
// decomposition then reports yaw = 0 and puts the whole rotation into roll, so
// euler -> matrix -> euler -> matrix reproduces the matrix.

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace lftrack::tracking {

using Pose = Eigen::Isometry3d;  // T_room_from_ct
using Vector6d = Eigen::Matrix<double, 6, 1>;

struct PoseDelta {
  Eigen::Vector3d translation_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d rotation_rad = Eigen::Vector3d::Zero();  // rotation vector (axis * angle)

  Vector6d as_vector() const;
  static PoseDelta from_vector(const Vector6d& v);
};

// Rotation by the rotation vector omega (Rodrigues; exact near zero).
Eigen::Matrix3d rotation_exp(const Eigen::Vector3d& omega_rad);
// Inverse of rotation_exp: a rotation vector with angle in [0, pi].
Eigen::Vector3d rotation_log(const Eigen::Matrix3d& rotation);

// T = Translation(t + c) * exp(omega) * Translation(-c) * T0, c in the room frame.
Pose apply_delta(const Pose& T0_room_from_ct, const PoseDelta& delta, const Eigen::Vector3d& origin_room_mm);
// The delta that takes T0 to T about c (inverse of apply_delta).
PoseDelta delta_between(const Pose& T0_room_from_ct, const Pose& T_room_from_ct,
                        const Eigen::Vector3d& origin_room_mm);

struct EulerAnglesRad {
  double roll = 0;   // about room x
  double pitch = 0;  // about room y, in [-pi/2, pi/2]
  double yaw = 0;    // about room z
};

Eigen::Matrix3d rotation_from_euler(const EulerAnglesRad& angles);
EulerAnglesRad euler_from_rotation(const Eigen::Matrix3d& rotation);

// Re-orthonormalises the rotation part (nearest rotation by SVD); for long compositions.
Pose orthonormalized(const Pose& pose);

inline double deg_to_rad(double deg) {
  return deg * (3.14159265358979323846 / 180.0);
}
inline double rad_to_deg(double rad) {
  return rad * (180.0 / 3.14159265358979323846);
}

}  // namespace lftrack::tracking
