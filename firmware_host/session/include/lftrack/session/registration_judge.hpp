#pragma once
// One registration judged end to end, as `lftrack register` and `lftrack commission` judge it and
// as the loop judges its alignment (cycle_verdict.cpp): the image-quality gate on each raw frame
// over its ROI window, preprocessing, the plan from a start pose, each view's check NCC (the
// frame against the DRR at the result), and the registration verdict (registration_verdict.hpp).
// Frames the gate refuses are not registered; their verdict says which view and why.

#include <functional>
#include <memory>
#include <vector>

#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/tracking/frame_quality.hpp"
#include "lftrack/tracking/registration.hpp"

namespace lftrack::session {

struct JudgedRegistration {
  bool registered = false;   // false: a frame failed the image-quality gate; nothing was registered
  loop::VerdictInput input;  // what the verdict judged
  double view_check_ms = 0;  // the view check's wall time (both views registered alone), when it ran
  loop::RegistrationVerdict verdict;
  std::vector<tracking::FrameQualityStats> quality;  // per view
  tracking::RegistrationResult result;               // when registered
};

// What the verdict judges of one result over frames already through the quality gate and
// preprocessing (`quality` per view): the stop, finiteness, each view's similarity, the delta from
// the nominal pose, and each view's check NCC against `renderer`'s DRR at the result (when the
// pose is finite). The studies judge their registrations with it; RegistrationJudge does too.
Result<loop::VerdictInput> verdict_input_of(const PreparedScene& scene, const tracking::DrrRenderer& renderer,
                                            const SceneFrames& frames,
                                            const std::vector<tracking::FrameQualityIssue>& quality,
                                            const tracking::RegistrationResult& result);

class RegistrationJudge {
 public:
  // Called with the preprocessed frames once the registration holds them, before the plan runs
  // (`lftrack register --fiducial` adds its term there).
  using BeforeRun = std::function<Status(const SceneFrames& frames, tracking::Registration* registration)>;

  // When the scene's view check (safety.max_view_shift_mm, view_agreement.hpp) runs: only for a
  // result everything else accepted (register, the loop), or for every registered result
  // (commission: the floors are chosen afterwards, knowing which wrong results the check refuses).
  enum class ViewCheck { kWhenOthersAccept, kAlways };

  // `renderer` renders both the registration's DRRs and the check's; `corrections` one per
  // detector, as scene_detector_corrections() gives them. The scene outlives the judge. With a
  // view check (judges_view_shift(limits)) each view's registration alone is made here, with the
  // scene's tracking plan.
  static Result<std::unique_ptr<RegistrationJudge>> create(
      const PreparedScene& scene, std::shared_ptr<const tracking::DrrRenderer> renderer,
      const RegistrationSpec& spec, std::vector<tracking::DetectorCorrection> corrections,
      const loop::VerdictLimits& limits, tracking::ThreadPool* pool,
      ViewCheck view_check = ViewCheck::kWhenOthersAccept);

  // Registers `raw` (whole-detector frames, one per view) from `start` with `plan` and judges it.
  Result<JudgedRegistration> judge(const std::vector<tracking::Image<std::uint16_t>>& raw,
                                   const tracking::Pose& start, const tracking::RegistrationPlan& plan,
                                   const BeforeRun& before_run = {});

  const loop::VerdictLimits& limits() const { return limits_; }
  const std::vector<tracking::DetectorCorrection>& corrections() const { return corrections_; }

 private:
  RegistrationJudge() = default;
  const PreparedScene* scene_ = nullptr;
  std::shared_ptr<const tracking::DrrRenderer> renderer_;
  std::unique_ptr<tracking::Registration> registration_;
  std::unique_ptr<loop::ViewAgreement> agreement_;  // null: the scene does not check its views alone
  ViewCheck view_check_ = ViewCheck::kWhenOthersAccept;
  std::vector<tracking::DetectorCorrection> corrections_;
  loop::VerdictLimits limits_;
};

}  // namespace lftrack::session
