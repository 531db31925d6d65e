// Numerical stability at the extremes: poses (docs/stability.md, "Poses"). Every case returns a
// defined, finite value.

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "lftrack/tracking/pose.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

constexpr double kPi = 3.14159265358979323846;

bool is_rotation(const Matrix3d& r, double tol) {
  return (r.transpose() * r - Matrix3d::Identity()).cwiseAbs().maxCoeff() < tol &&
         std::abs(r.determinant() - 1) < tol;
}

TEST(StabilityPose, EulerAnglesAtPlusMinus90DegreesRoundTripTheMatrix) {
  for (double pitch : {kPi / 2, -kPi / 2, kPi / 2 - 1e-12, -kPi / 2 + 1e-12, kPi / 2 - 1e-7}) {
    for (double roll : {0.0, 0.3, -2.9}) {
      const Matrix3d r = rotation_from_euler({roll, pitch, 0.7});
      const EulerAnglesRad e = euler_from_rotation(r);
      ASSERT_TRUE(std::isfinite(e.roll) && std::isfinite(e.pitch) && std::isfinite(e.yaw));
      EXPECT_LE(std::abs(e.pitch), kPi / 2 + 1e-12);
      EXPECT_LT((rotation_from_euler(e) - r).cwiseAbs().maxCoeff(), 1e-6) << pitch << " " << roll;
    }
  }
  // A matrix a hair beyond +-1 in the pitch term (rounding) still decomposes.
  Matrix3d r = rotation_from_euler({0.2, kPi / 2, 0.1});
  r(2, 0) = -1.0000000000000002;
  const EulerAnglesRad e = euler_from_rotation(r);
  EXPECT_TRUE(std::isfinite(e.roll) && std::isfinite(e.pitch) && std::isfinite(e.yaw));
}

TEST(StabilityPose, RotationsNearPiLogToAnAngleOfPi) {
  for (double angle : {kPi, kPi - 1e-6, kPi - 1e-12, kPi + 1e-9}) {
    for (const Vector3d& axis :
         {Vector3d(1, 0, 0), Vector3d(0, 1, 1).normalized(), Vector3d(-1, 2, 3).normalized()}) {
      const Matrix3d r = rotation_exp(axis * angle);
      ASSERT_TRUE(is_rotation(r, 1e-12));
      const Vector3d w = rotation_log(r);
      ASSERT_TRUE(w.allFinite());
      EXPECT_LE(w.norm(), kPi + 1e-12);
      EXPECT_LT((rotation_exp(w) - r).cwiseAbs().maxCoeff(), 1e-9) << angle;
    }
  }
}

TEST(StabilityPose, RotationsOf1e12RadKeepTheirSize) {
  for (const Vector3d& w : {Vector3d(1e-12, 0, 0), Vector3d(0, -1e-12, 1e-12), Vector3d(1e-300, 0, 0)}) {
    const Matrix3d r = rotation_exp(w);
    ASSERT_TRUE(r.allFinite());
    EXPECT_TRUE(is_rotation(r, 1e-15));
    // exp is exact to first order: R - I = [w]x.
    EXPECT_NEAR(r(2, 1), w.x(), 1e-24);
    const Vector3d back = rotation_log(r);
    ASSERT_TRUE(back.allFinite());
    EXPECT_LT((back - w).norm(), 1e-15);
  }
  EXPECT_EQ(rotation_log(Matrix3d::Identity()), Vector3d::Zero());
}

TEST(StabilityPose, TranslationsOfKilometresStayExactToRelativePrecision) {
  const Pose T0 = Pose::Identity();
  for (double km : {1.0, 1000.0}) {
    PoseDelta d;
    d.translation_mm = Vector3d(km * 1e6, -km * 1e6, 0.5);
    d.rotation_rad = Vector3d(0.01, 0.02, -0.03);
    const Vector3d origin(3e6, 0, -2e6);
    const Pose T = apply_delta(T0, d, origin);
    ASSERT_TRUE(T.matrix().allFinite());
    const PoseDelta back = delta_between(T0, T, origin);
    EXPECT_LT((back.translation_mm - d.translation_mm).norm(), 1e-13 * km * 1e6);  // ~500 ulp
    EXPECT_LT((back.rotation_rad - d.rotation_rad).norm(), 1e-12);
  }
}

// 10^6 small increments: without re-orthonormalisation the rotation drifts from SO(3);
// orthonormalized() restores it, and the composed angle is the sum of the increments.
TEST(StabilityPose, AMillionSmallIncrementsStayARotationWhenReorthonormalised) {
  const Vector3d axis = Vector3d(1, -2, 0.5).normalized();
  const double step = 1e-6;  // rad
  Pose drifting = Pose::Identity(), kept = Pose::Identity();
  PoseDelta d;
  d.rotation_rad = axis * step;
  d.translation_mm = Vector3d(1e-6, 0, 0);
  for (int n = 0; n < 1'000'000; ++n) {
    drifting = apply_delta(drifting, d, Vector3d::Zero());
    kept = apply_delta(kept, d, Vector3d::Zero());
    if (n % 1000 == 999) kept = orthonormalized(kept);
  }
  ASSERT_TRUE(drifting.matrix().allFinite());
  EXPECT_TRUE(is_rotation(kept.linear(), 1e-12));
  EXPECT_NEAR(rotation_log(kept.linear()).norm(), 1.0, 1e-6);  // 10^6 x 1e-6 rad
  EXPECT_LT((rotation_log(kept.linear()).normalized() - axis).norm(), 1e-9);
  // What the drift amounts to, for docs/stability.md: measurable, but small at double precision.
  const double drift =
      (drifting.linear().transpose() * drifting.linear() - Matrix3d::Identity()).cwiseAbs().maxCoeff();
  EXPECT_LT(drift, 1e-8);
  RecordProperty("orthonormality_drift_after_1e6", std::to_string(drift));
}

TEST(StabilityPose, OrthonormalizeRepairsBadlyDamagedAndRefusesNothing) {
  Pose p = Pose::Identity();
  p.linear() << 1.1, 0.05, 0, -0.02, 0.9, 0.01, 0, 0.03, 1.2;
  EXPECT_TRUE(is_rotation(orthonormalized(p).linear(), 1e-12));
  Pose reflected = Pose::Identity();
  reflected.linear() = Vector3d(1, 1, -1).asDiagonal();
  const Pose q = orthonormalized(reflected);
  ASSERT_TRUE(q.matrix().allFinite());
  EXPECT_NEAR(q.linear().determinant(), 1.0, 1e-12);
}

}  // namespace
}  // namespace lftrack::tracking
