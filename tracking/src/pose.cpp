#include "lftrack/tracking/pose.hpp"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>

namespace lftrack::tracking {

Vector6d PoseDelta::as_vector() const {
  Vector6d v;
  v << translation_mm, rotation_rad;
  return v;
}

PoseDelta PoseDelta::from_vector(const Vector6d& v) {
  return {v.head<3>(), v.tail<3>()};
}

Eigen::Matrix3d rotation_exp(const Eigen::Vector3d& omega) {
  const double theta = omega.norm();
  Eigen::Matrix3d k;
  k << 0, -omega.z(), omega.y(), omega.z(), 0, -omega.x(), -omega.y(), omega.x(), 0;
  double a, b;  // sin(theta)/theta and (1 - cos(theta))/theta^2, by Taylor series near 0
  if (theta < 1e-4) {
    const double t2 = theta * theta;
    a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0;
    b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0;
  } else {
    a = std::sin(theta) / theta;
    b = (1.0 - std::cos(theta)) / (theta * theta);
  }
  return Eigen::Matrix3d::Identity() + a * k + b * k * k;
}

Eigen::Vector3d rotation_log(const Eigen::Matrix3d& r) {
  // Eigen's AngleAxis handles angles near 0 and near pi robustly (it uses the quaternion).
  const Eigen::AngleAxisd aa(Eigen::Quaterniond(r).normalized());
  double angle = aa.angle();
  Eigen::Vector3d axis = aa.axis();
  if (angle > M_PI) {
    angle = 2 * M_PI - angle;
    axis = -axis;
  }
  return axis * angle;
}

Pose apply_delta(const Pose& T0, const PoseDelta& delta, const Eigen::Vector3d& c) {
  Pose step = Pose::Identity();
  step.linear() = rotation_exp(delta.rotation_rad);
  step.translation() = delta.translation_mm + c - step.linear() * c;
  return step * T0;
}

PoseDelta delta_between(const Pose& T0, const Pose& T, const Eigen::Vector3d& c) {
  const Pose step = T * T0.inverse();
  PoseDelta d;
  d.rotation_rad = rotation_log(step.linear());
  d.translation_mm = step.translation() - c + step.linear() * c;
  return d;
}

Eigen::Matrix3d rotation_from_euler(const EulerAnglesRad& e) {
  return (Eigen::AngleAxisd(e.yaw, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(e.pitch, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(e.roll, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

EulerAnglesRad euler_from_rotation(const Eigen::Matrix3d& r) {
  // R = Rz(y) Ry(p) Rx(r):  R(2,0) = -sin p,  R(2,1) = cos p sin r,  R(2,2) = cos p cos r,
  //                         R(1,0) = sin y cos p,  R(0,0) = cos y cos p.
  EulerAnglesRad e;
  const double sp = std::clamp(-r(2, 0), -1.0, 1.0);
  const double cp = std::hypot(r(0, 0), r(1, 0));
  e.pitch = std::atan2(sp, cp);
  if (cp > 1e-9) {
    e.roll = std::atan2(r(2, 1), r(2, 2));
    e.yaw = std::atan2(r(1, 0), r(0, 0));
  } else {
    // Gimbal lock: only roll - yaw (pitch = +90) or roll + yaw (pitch = -90) is defined.
    // Report yaw = 0; then R = Ry(p) Rx(roll) and roll follows from R(0,1), R(1,1).
    e.yaw = 0.0;
    e.roll = std::atan2(sp > 0 ? r(0, 1) : -r(0, 1), r(1, 1));
  }
  return e;
}

Pose orthonormalized(const Pose& pose) {
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(pose.linear(), Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d r = svd.matrixU() * svd.matrixV().transpose();
  if (r.determinant() < 0) {
    Eigen::Matrix3d u = svd.matrixU();
    u.col(2) *= -1;
    r = u * svd.matrixV().transpose();
  }
  Pose out = pose;
  out.linear() = r;
  return out;
}

}  // namespace lftrack::tracking
