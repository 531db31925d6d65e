#include "lftrack/loop/loop_registration.hpp"

#include <utility>

namespace lftrack::loop {

Status PlannedRegistration::prepare(const tracking::RegistrationPlan& align, const tracking::RegistrationPlan& track) {
  auto align_prepared = registration_->prepare_plan(align);
  if (!align_prepared.ok()) return align_prepared.status().with_context("align plan");
  auto track_prepared = registration_->prepare_plan(track);
  if (!track_prepared.ok()) return track_prepared.status().with_context("track plan");
  align_ = std::move(align_prepared).value();
  track_ = std::move(track_prepared).value();
  return {};
}

Status PlannedRegistration::set_frames(const std::vector<tracking::ImageView<const float>>& frames,
                                       const std::vector<tracking::ImageView<const unsigned char>>& valid) {
  return registration_->set_frames(frames, valid);
}

Status PlannedRegistration::run(const tracking::Pose& start_T_room_from_ct, RegistrationStage stage, double max_ms,
                                tracking::RegistrationResult* result) {
  return registration_->run(start_T_room_from_ct, stage == RegistrationStage::kAlign ? align_ : track_, max_ms,
                            result);
}

}  // namespace lftrack::loop
