#include "lftrack/calib/triangulation.hpp"

#include <gtest/gtest.h>

#include <random>

#include "lftrack/tracking/pose.hpp"

namespace lftrack::calib {
namespace {

using Eigen::Vector3d;
using tracking::XrayView;

TEST(Triangulate, RecoversAPointSeenByTwoViews) {
  const XrayView a = *XrayView::isocentric("A", Vector3d::Zero(), Vector3d(1, -1, 0), Vector3d(0, 0, 1), 1500,
                                           2100, 512, 512, 0.4);
  const XrayView b = *XrayView::isocentric("B", Vector3d::Zero(), Vector3d(-1, -1, 0), Vector3d(0, 0, 1),
                                           1500, 2100, 512, 512, 0.4);
  const Vector3d p(12.5, -7.25, 30.0);
  auto t = triangulate(a, *a.project(p), b, *b.project(p));
  ASSERT_TRUE(t.ok());
  EXPECT_LT((t->point_mm - p).norm(), 1e-9);
  EXPECT_LT(t->gap_mm, 1e-9);
  // A pixel off by one in view A: the rays miss each other and the gap says by how much.
  auto off = triangulate(a, *a.project(p) + Eigen::Vector2d(0, 1), b, *b.project(p));
  ASSERT_TRUE(off.ok());
  EXPECT_GT(off->gap_mm, 0.1);
  EXPECT_FALSE(triangulate(a, *a.project(p), a, *a.project(p)).ok());  // parallel rays
}

TEST(FitRigid, RecoversTransformAndGuardsAgainstReflection) {
  std::mt19937 rng(9);
  std::normal_distribution<double> n(0, 30);
  std::vector<Vector3d> from, to;
  Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
  truth.linear() = tracking::rotation_exp(Vector3d(0.2, -1.4, 0.7));
  truth.translation() = Vector3d(-284.1, -247.0, -226.7);
  for (int i = 0; i < 6; ++i) {
    from.emplace_back(n(rng), n(rng), n(rng));
    to.push_back(truth * from.back());
  }
  auto fit = fit_rigid(from, to);
  ASSERT_TRUE(fit.ok());
  EXPECT_TRUE(fit->T_to_from.matrix().isApprox(truth.matrix(), 1e-9));
  EXPECT_LT(fit->fre_rms_mm, 1e-9);
  // Mirror the targets: the best orthogonal map is a reflection; the fit must stay a rotation.
  for (auto& p : to) p.x() = -p.x();
  auto mirrored = fit_rigid(from, to);
  ASSERT_TRUE(mirrored.ok());
  EXPECT_NEAR(mirrored->T_to_from.linear().determinant(), 1.0, 1e-9);
  EXPECT_GT(mirrored->fre_rms_mm, 1.0);
}

TEST(FitRigid, RejectsDegenerateInput) {
  EXPECT_FALSE(fit_rigid({Vector3d::Zero(), Vector3d::UnitX()}, {Vector3d::Zero(), Vector3d::UnitX()}).ok());
  const std::vector<Vector3d> line = {Vector3d(0, 0, 0), Vector3d(1, 0, 0), Vector3d(2, 0, 0)};
  EXPECT_FALSE(fit_rigid(line, line).ok());
  EXPECT_FALSE(fit_rigid(line, {Vector3d::Zero()}).ok());
}

}  // namespace
}  // namespace lftrack::calib
