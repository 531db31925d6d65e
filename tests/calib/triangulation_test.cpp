#include "lftrack/calib/triangulation.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/random_draws.hpp"

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
    from.push_back(tracking::draw3(n, rng));
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
  // Repeated points carry no more than one point does.
  const std::vector<Vector3d> repeated(5, Vector3d(1, 2, 3));
  auto r = fit_rigid(repeated, repeated);
  ASSERT_FALSE(r.ok());
  EXPECT_FALSE(r.status().message().empty());
  // Non-finite input.
  EXPECT_FALSE(fit_rigid({Vector3d(0, 0, 0), Vector3d(1, 0, 0), Vector3d(0, NAN, 0)},
                         {Vector3d(0, 0, 0), Vector3d(1, 0, 0), Vector3d(0, 1, 0)})
                   .ok());
}

TEST(FitRigid, FreIsTheRmsResidualOfNoisyPoints) {
  // Four fiducials (two tacks ~25 mm apart and two more, as in paper 2), moved and perturbed.
  const std::vector<Vector3d> ct = {Vector3d(0, 0, 0), Vector3d(25, 0, 0), Vector3d(0, 30, 5), Vector3d(10, 10, 40)};
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = tracking::rotation_exp(Vector3d(0.1, -0.2, 0.3));
  T.translation() = Vector3d(-284.1, -247.0, -226.7);
  const std::vector<Vector3d> noise = {Vector3d(0.1, 0, 0), Vector3d(0, -0.1, 0), Vector3d(0, 0, 0.1),
                                       Vector3d(-0.1, 0.1, 0)};
  std::vector<Vector3d> room;
  for (std::size_t i = 0; i < ct.size(); ++i) room.push_back(T * ct[i] + noise[i]);
  auto fit = fit_rigid(ct, room);
  ASSERT_TRUE(fit.ok());
  double sum = 0;
  for (std::size_t i = 0; i < ct.size(); ++i) sum += (fit->T_to_from * ct[i] - room[i]).squaredNorm();
  EXPECT_NEAR(fit->fre_rms_mm, std::sqrt(sum / 4), 1e-9);
  EXPECT_LT(fit->fre_rms_mm, 0.15);
  EXPECT_LT((fit->T_to_from.translation() - T.translation()).norm(), 0.5);
}

TEST(Triangulate, RefusesNearlyParallelAndNonFiniteInput) {
  const XrayView a = *XrayView::isocentric("A", Vector3d::Zero(), Vector3d(1, -1, 0), Vector3d(0, 0, 1), 1500,
                                           2100, 512, 512, 0.4);
  // The same view moved sideways: every pair of rays is parallel.
  XrayView shifted = a;
  shifted.source_mm += Vector3d(0, 0, 10);
  shifted.pixel00_mm += Vector3d(0, 0, 10);
  auto t = triangulate(a, {100, 100}, shifted, {100, 100});
  ASSERT_FALSE(t.ok());
  EXPECT_NE(t.status().message().find("parallel"), std::string::npos) << t.status().message();
  EXPECT_FALSE(triangulate(a, {NAN, 100}, shifted, {100, 100}).ok());
}

}  // namespace
}  // namespace lftrack::calib
