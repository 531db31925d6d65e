#include <gtest/gtest.h>

#include <random>

#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/random_draws.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

TEST(RotationExp, MatchesAngleAxisAndIsExactNearZero) {
  const Vector3d omega(0.3, -0.2, 0.9);
  EXPECT_TRUE(rotation_exp(omega).isApprox(
      Eigen::AngleAxisd(omega.norm(), omega.normalized()).toRotationMatrix(), 1e-12));
  const Vector3d tiny(1e-12, -2e-12, 3e-12);
  const Matrix3d r = rotation_exp(tiny);
  EXPECT_TRUE((r.transpose() * r).isApprox(Matrix3d::Identity(), 1e-15));
  EXPECT_NEAR(r(2, 1), 1e-12 + 0.5 * (-2e-12) * 3e-12, 1e-27);  // w_x + w_y w_z / 2
  EXPECT_TRUE(rotation_log(r).isApprox(tiny, 1e-9));
}

TEST(RotationLog, InvertsExpUpToPi) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int n = 0; n < 200; ++n) {
    Vector3d axis = tracking::draw3(u, rng);
    axis.normalize();
    const double angle = 3.14159 * std::abs(u(rng));
    const Vector3d w = axis * angle;
    EXPECT_TRUE(rotation_log(rotation_exp(w)).isApprox(w, 1e-9)) << w.transpose();
  }
  // Exactly pi: the axis is recovered up to sign.
  const Vector3d half_turn(0, M_PI, 0);
  const Vector3d back = rotation_log(rotation_exp(half_turn));
  EXPECT_NEAR(back.norm(), M_PI, 1e-9);
  EXPECT_TRUE(rotation_exp(back).isApprox(rotation_exp(half_turn), 1e-12));
}

TEST(PoseDelta, RotatesAboutTheRegistrationOrigin) {
  const Vector3d c(10, -20, 30);
  Pose t0 = Pose::Identity();
  t0.translation() = Vector3d(1, 2, 3);
  PoseDelta d;
  d.rotation_rad = Vector3d(0, 0, 0.5);
  const Pose t = apply_delta(t0, d, c);
  // The point of the CT that sat on c stays on c.
  const Vector3d ct_point_at_c = t0.inverse() * c;
  EXPECT_TRUE((t * ct_point_at_c).isApprox(c, 1e-12));
  // A translation-only delta moves every point by t.
  PoseDelta shift;
  shift.translation_mm = Vector3d(4, 5, 6);
  EXPECT_TRUE(
      (apply_delta(t0, shift, c) * Vector3d(7, 8, 9)).isApprox(t0 * Vector3d(7, 8, 9) + Vector3d(4, 5, 6)));
}

TEST(PoseDelta, DeltaBetweenInvertsApplyDelta) {
  const Vector3d c(-5, 3, 80);
  Pose t0 = Pose::Identity();
  t0.linear() = rotation_exp(Vector3d(0.1, 0.2, -0.3));
  t0.translation() = Vector3d(-284.1, -247.0, -226.7);
  PoseDelta d;
  d.translation_mm = Vector3d(3, -8, 1.5);
  d.rotation_rad = Vector3d(0.05, -0.07, 0.02);
  const PoseDelta back = delta_between(t0, apply_delta(t0, d, c), c);
  EXPECT_TRUE(back.as_vector().isApprox(d.as_vector(), 1e-10));
}

TEST(EulerAngles, RoundTripIncludingGimbalLock) {
  for (double pitch_deg : {-90.0, -89.9999, -45.0, 0.0, 30.0, 89.9999, 90.0}) {
    for (double roll_deg : {-170.0, -90.4, 0.0, 12.0}) {
      for (double yaw_deg : {-89.9, 0.0, 45.0, 179.0}) {
        const EulerAnglesRad e{deg_to_rad(roll_deg), deg_to_rad(pitch_deg), deg_to_rad(yaw_deg)};
        const Matrix3d r = rotation_from_euler(e);
        const EulerAnglesRad back = euler_from_rotation(r);
        EXPECT_TRUE(rotation_from_euler(back).isApprox(r, 1e-9))
            << roll_deg << " " << pitch_deg << " " << yaw_deg;
        EXPECT_TRUE(std::isfinite(back.roll) && std::isfinite(back.pitch) && std::isfinite(back.yaw));
      }
    }
  }
}

TEST(EulerAngles, PapersGoldStandardAtMinus90) {
  // Paper 1, patient 1: angles (-90.4, -0.1, -89.9) degrees.
  const EulerAnglesRad e{deg_to_rad(-90.4), deg_to_rad(-0.1), deg_to_rad(-89.9)};
  const EulerAnglesRad back = euler_from_rotation(rotation_from_euler(e));
  EXPECT_NEAR(rad_to_deg(back.roll), -90.4, 1e-9);
  EXPECT_NEAR(rad_to_deg(back.pitch), -0.1, 1e-9);
  EXPECT_NEAR(rad_to_deg(back.yaw), -89.9, 1e-9);
}

TEST(Orthonormalize, RepairsDriftFromManyCompositions) {
  Pose p = Pose::Identity();
  const Matrix3d step = rotation_exp(Vector3d(1e-4, -2e-4, 3e-4));
  for (int n = 0; n < 100000; ++n) p.linear() = (step * p.linear()).eval();
  const Pose fixed = orthonormalized(p);
  EXPECT_TRUE((fixed.linear().transpose() * fixed.linear()).isApprox(Matrix3d::Identity(), 1e-14));
  EXPECT_NEAR(fixed.linear().determinant(), 1.0, 1e-14);
  EXPECT_TRUE(fixed.linear().isApprox(p.linear(), 1e-9));
}

}  // namespace
}  // namespace lftrack::tracking
