#include "lftrack/loop/view_agreement.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace lftrack::loop {

double shift_across_ray_mm(const Eigen::Vector3d& at_room_mm, const Eigen::Vector3d& moved_room_mm,
                           const Eigen::Vector3d& ray_room) {
  const Eigen::Vector3d d = moved_room_mm - at_room_mm;
  return (d - d.dot(ray_room) * ray_room).norm();
}

tracking::RegistrationPlan view_check_plan(const tracking::RegistrationPlan& tracking_plan) {
  tracking::RegistrationPlan plan;
  plan.name = tracking_plan.name + " (each view alone: translations, last level)";
  tracking::RegistrationPass pass;
  if (!tracking_plan.passes.empty()) pass = tracking_plan.passes.back();
  pass.optimizer = "quadratic-neighbour";
  pass.translations_only = true;
  pass.bin = std::max(pass.bin, 2);
  pass.initial_step_mm = 1.0;
  pass.final_step_mm = 0.25;
  pass.tolerance_mm = 0;
  pass.max_evaluations = 200;
  plan.passes = {pass};
  return plan;
}

Result<std::unique_ptr<ViewAgreement>> ViewAgreement::create(std::vector<View> views,
                                                             const tracking::RegistrationPlan& tracking_plan,
                                                             const Eigen::Vector3d& origin_room_mm) {
  const tracking::RegistrationPlan plan = view_check_plan(tracking_plan);
  if (views.empty() || views.size() > std::size_t(kMaxVerdictViews))
    return invalid_argument("view agreement: 1 to " + std::to_string(kMaxVerdictViews) + " views");
  std::unique_ptr<ViewAgreement> a(new ViewAgreement);
  for (View& v : views) {
    if (!v.registration) return invalid_argument("view agreement: a view without its registration");
    if (v.registration->setup().views.size() != 1)
      return invalid_argument("view agreement: each view's registration must hold that view alone");
    if ((origin_room_mm - v.source_room_mm).norm() < 1e-6)
      return invalid_argument("view agreement: a source at the registration origin");
    auto prepared = v.registration->prepare_plan(plan);
    if (!prepared.ok()) return prepared.status().with_context("view agreement: plan " + plan.name);
    a->plans_.push_back(std::move(prepared).value());
  }
  a->views_ = std::move(views);
  a->results_.resize(a->views_.size());
  a->origin_room_mm_ = origin_room_mm;
  a->one_frame_.resize(1);
  a->one_mask_.resize(1);
  return a;
}

Status ViewAgreement::set_frames(const std::vector<tracking::ImageView<const float>>& frames,
                                 const std::vector<tracking::ImageView<const unsigned char>>& valid) {
  if (frames.size() != views_.size() || valid.size() != views_.size())
    return invalid_argument("view agreement: one frame and one mask per view");
  for (std::size_t v = 0; v < views_.size(); ++v) {
    one_frame_[0] = frames[v];
    one_mask_[0] = valid[v];
    LFTRACK_RETURN_IF_ERROR(views_[v].registration->set_frames(one_frame_, one_mask_));
  }
  return {};
}

Status ViewAgreement::measure(const tracking::Pose& joint, double max_ms, std::array<double, kMaxVerdictViews>* shift_mm,
                              bool* complete) {
  *complete = true;
  // The CT point at the target under the joint result; where each view alone puts it.
  const Eigen::Vector3d target_ct = joint.inverse() * origin_room_mm_;
  for (std::size_t v = 0; v < views_.size(); ++v) {
    tracking::RegistrationResult& r = results_[v];
    LFTRACK_RETURN_IF_ERROR(views_[v].registration->run(joint, plans_[v], max_ms, &r));
    if (r.stop == tracking::OptimizerStop::kTimeBudget) *complete = false;
    const Eigen::Vector3d ray = (origin_room_mm_ - views_[v].source_room_mm).normalized();
    (*shift_mm)[v] = r.stop == tracking::OptimizerStop::kNonFinite
                         ? std::numeric_limits<double>::quiet_NaN()
                         : shift_across_ray_mm(origin_room_mm_, r.T_room_from_ct * target_ct, ray);
  }
  return {};
}

}  // namespace lftrack::loop
