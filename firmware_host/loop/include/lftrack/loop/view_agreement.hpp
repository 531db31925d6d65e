#pragma once
// Do the views agree? Each view registered alone, warm from a joint result, with the tracking
// plan: where both views see the same anatomy at the same pose, neither alone moves the target
// by more than the registration's noise; where the joint result is a compromise (one frame of
// another level, a view blocked or mirrored, anatomy that moved in one view's line of sight),
// the view that disagrees pulls the target towards its own answer. The registration verdict
// (registration_verdict.hpp) refuses a shift beyond the scene's safety.max_view_shift_mm.
//
// One view cannot see depth along its ray through the target, so the shift is measured across
// the view only: the target's displacement with its component along the ray from the view's
// source through the target (at the joint result) left out, mm at the target.
//
// create() allocates; after the first measure() of a frame size, set_frames() and measure()
// allocate nothing (each view's registration keeps its buffers), so the loop may call them in a
// tracking cycle.

#include <Eigen/Core>
#include <array>
#include <memory>
#include <vector>

#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/registration.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::loop {

// The displacement of the target, `moved - at`, less its component along the unit ray
// `ray_room`: what a view along that ray sees of it. Pure.
double shift_across_ray_mm(const Eigen::Vector3d& at_room_mm, const Eigen::Vector3d& moved_room_mm,
                           const Eigen::Vector3d& ray_room);

// The plan each view is registered alone with, from the scene's tracking plan: its last pass (the
// measure and image level that tracking ends on) with the translations alone (the target's shift
// is what is judged; one view fixes rotations poorly, and letting them move made the search
// three to five times as long: 55-310 ms a result with the whole tracking plan on the lumbar
// clinical scene), on images binned at least 2 x 2, 1 -> 0.25 mm.
tracking::RegistrationPlan view_check_plan(const tracking::RegistrationPlan& tracking_plan);

class ViewAgreement {
 public:
  struct View {
    std::unique_ptr<tracking::Registration> registration;  // over this view's window alone
    Eigen::Vector3d source_room_mm = Eigen::Vector3d::Zero();
  };
  // One single-view registration per view, in the joint registration's view order;
  // view_check_plan(tracking_plan) is prepared on each; `origin_room_mm` is the registration
  // origin (the target the shift is measured at).
  static Result<std::unique_ptr<ViewAgreement>> create(std::vector<View> views,
                                                       const tracking::RegistrationPlan& tracking_plan,
                                                       const Eigen::Vector3d& origin_room_mm);

  int views() const { return static_cast<int>(views_.size()); }
  // The views' preprocessed frames and masks, as the joint registration got them (copied).
  Status set_frames(const std::vector<tracking::ImageView<const float>>& frames,
                    const std::vector<tracking::ImageView<const unsigned char>>& valid);
  // Registers each view alone from `joint_T_room_from_ct` within `max_ms` each (wall time; the
  // plan's own budget too), and writes each view's shift across it into `shift_mm`. `complete`
  // is false when a view's search was stopped by the budget: its shift is then not a verdict.
  Status measure(const tracking::Pose& joint_T_room_from_ct, double max_ms,
                 std::array<double, kMaxVerdictViews>* shift_mm, bool* complete);

 private:
  ViewAgreement() = default;
  std::vector<View> views_;
  std::vector<tracking::PreparedPlan> plans_;
  std::vector<tracking::RegistrationResult> results_;
  Eigen::Vector3d origin_room_mm_ = Eigen::Vector3d::Zero();
  std::vector<tracking::ImageView<const float>> one_frame_;
  std::vector<tracking::ImageView<const unsigned char>> one_mask_;
};

}  // namespace lftrack::loop
