// The verdict's view check (view_agreement.hpp): each view registered alone from the joint
// result. Two views of one pose leave the result where it is; a pair whose views saw the patient
// at poses 4 mm apart (one frame stale, or of a moved patient) registers to a compromise that
// each view alone pulls away from, and the verdict refuses it naming the view. On the shipped
// DICOM CT, two coarse ray-cast views: quick to register.

#include "lftrack/loop/view_agreement.hpp"

#include <gtest/gtest.h>

#include <memory>

#include "lftrack/session/registration_judge.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/session/scene_verdict.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using sim_devices::scene_detector_model;
using sim_devices::synthesize_scene_frames;

using loop::judge_registration;
using loop::RegistrationVerdict;
using loop::shift_across_ray_mm;
using loop::verdict_text;
using loop::VerdictLimits;
using loop::VerdictReason;
using loop::ViewAgreement;
namespace {

using Eigen::Vector3d;

TEST(ViewAgreement, OnlyTheShiftAcrossTheRayCounts) {
  const Vector3d at(1, 2, 3), ray = Vector3d(1, -1, 0).normalized();
  EXPECT_NEAR(shift_across_ray_mm(at, at + 7.5 * ray, ray), 0, 1e-12) << "depth along the ray is unseen";
  EXPECT_NEAR(shift_across_ray_mm(at, at + Vector3d(0, 0, 2), ray), 2, 1e-12);
  EXPECT_NEAR(shift_across_ray_mm(at, at + 3 * ray + Vector3d(0, 0, -1.5), ray), 1.5, 1e-12);
}

class ViewCheck : public ::testing::Test {
 protected:
  void SetUp() override {
    LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
    auto scene = parse_scene(test::lumbar_two_coarse_views_scene(), "views.yaml", ".");
    ASSERT_TRUE(scene.ok()) << scene.status().message();
    auto p = prepare_scene(*scene, "", &pool_);
    ASSERT_TRUE(p.ok()) << p.status().message();
    p_ = std::make_unique<PreparedScene>(std::move(p).value());
    tracking::RendererOptions options;
    options.pool = &pool_;
    exact_ = std::move(tracking::make_renderer("siddon", p_->mu, options)).value();
  }
  std::vector<tracking::Image<std::uint16_t>> frames_at(const std::vector<double>& a, const std::vector<double>& b) {
    auto raw_a = synthesize_scene_frames(*p_, *exact_, *pose_from_nominal_delta(*p_, a), 5);
    auto raw_b = synthesize_scene_frames(*p_, *exact_, *pose_from_nominal_delta(*p_, b), 6);
    EXPECT_TRUE(raw_a.ok() && raw_b.ok());
    return {(*raw_a)[0], (*raw_b)[1]};
  }
  Result<JudgedRegistration> judge(const std::vector<tracking::Image<std::uint16_t>>& raw) {
    auto limits = verdict_limits(p_->scene, p_->scene.registration.similarity);
    if (!limits.ok()) return limits.status();
    const tracking::DetectorCorrection correction = sim::detector_correction(scene_detector_model(*p_));
    auto judge = RegistrationJudge::create(*p_, exact_, p_->scene.registration, {correction, correction}, *limits,
                                           &pool_, RegistrationJudge::ViewCheck::kAlways);
    if (!judge.ok()) return judge.status();
    return (*judge)->judge(raw, p_->nominal_T_room_from_ct, *tracking::registration_plan("quadratic"));
  }
  tracking::ThreadPool pool_{2};
  std::unique_ptr<PreparedScene> p_;
  std::shared_ptr<const tracking::DrrRenderer> exact_;
};

TEST_F(ViewCheck, TwoViewsOfOnePoseLeaveTheResultInPlace) {
  auto judged = judge(frames_at({1.5, -1, 1, 1, 0.5, -0.5}, {1.5, -1, 1, 1, 0.5, -0.5}));
  ASSERT_TRUE(judged.ok()) << judged.status().message();
  ASSERT_TRUE(judged->input.has_view_shift);
  EXPECT_TRUE(judged->verdict.ok) << verdict_text(judged->verdict, {"A", "B"});
  for (int v = 0; v < 2; ++v) EXPECT_LT(judged->input.view_shift_mm[std::size_t(v)], 0.5) << v;
  EXPECT_GT(judged->view_check_ms, 0);
}

TEST_F(ViewCheck, ViewsOfPosesApartPullTheCompromiseApartAndAreRefused) {
  // View B saw the patient 4 mm further towards the head (across B, as across A).
  auto judged = judge(frames_at({1.5, -1, 1, 1, 0.5, -0.5}, {1.5, -1, 5, 1, 0.5, -0.5}));
  ASSERT_TRUE(judged.ok()) << judged.status().message();
  ASSERT_TRUE(judged->input.has_view_shift);
  const double most = std::max(judged->input.view_shift_mm[0], judged->input.view_shift_mm[1]);
  EXPECT_GT(most, 1.0) << "each view alone goes back towards its own pose";
  // Whatever else the verdict says of such a pair, it is never accepted.
  EXPECT_FALSE(judged->verdict.ok);
  VerdictLimits open = *verdict_limits(p_->scene, p_->scene.registration.similarity);
  open.min_similarity = open.min_check_ncc = -1e9;
  open.min_view_ratio = 0;
  open.envelope_edge_mm = 0;
  const RegistrationVerdict view_check_alone = judge_registration(open, judged->input);
  EXPECT_EQ(view_check_alone.reason, VerdictReason::kViewsPullApart) << verdict_text(view_check_alone, {"A", "B"});
}

TEST_F(ViewCheck, AWrongAgreementIsRefusedAtCreation) {
  std::vector<ViewAgreement::View> none;
  EXPECT_FALSE(ViewAgreement::create(std::move(none), *tracking::registration_plan("warm"), Vector3d::Zero()).ok());
  auto joint = make_scene_registration(*p_, exact_, p_->scene.registration, &pool_);
  ASSERT_TRUE(joint.ok());
  std::vector<ViewAgreement::View> both_views;
  both_views.push_back({std::move(joint).value(), Vector3d(1000, 0, 0)});
  auto refused = ViewAgreement::create(std::move(both_views), *tracking::registration_plan("warm"), Vector3d::Zero());
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("that view alone"), std::string::npos) << refused.status().message();
}

}  // namespace
}  // namespace lftrack::session
