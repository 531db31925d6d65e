#include "lftrack/session/registration_judge.hpp"

#include <chrono>

namespace lftrack::session {

using loop::judge_registration;
using loop::judges_view_shift;
using loop::kMaxVerdictViews;
using loop::masked_ncc;
using loop::VerdictInput;
using loop::VerdictLimits;

using tracking::Image;

Result<VerdictInput> verdict_input_of(const PreparedScene& p, const tracking::DrrRenderer& renderer,
                                      const SceneFrames& frames,
                                      const std::vector<tracking::FrameQualityIssue>& quality,
                                      const tracking::RegistrationResult& result) {
  const std::size_t views = p.scene.detectors.size();
  if (views < 1 || views > std::size_t(kMaxVerdictViews)) return invalid_argument("more views than the verdict holds");
  if (quality.size() != views || frames.line_integral.size() != views || frames.valid.size() != views)
    return invalid_argument("verdict input: one frame and one quality per view");
  VerdictInput in;
  in.views = static_cast<int>(views);
  for (std::size_t v = 0; v < views; ++v) in.image_quality[v] = quality[v];
  in.stop = result.stop;
  in.pose_finite = result.T_room_from_ct.matrix().allFinite();
  for (std::size_t v = 0; v < result.view_similarity.size() && v < in.similarity.size(); ++v)
    in.similarity[v] = result.view_similarity[v];
  in.delta_from_nominal =
      tracking::delta_between(p.nominal_T_room_from_ct, result.T_room_from_ct, p.registration_origin_room_mm())
          .as_vector();
  if (in.pose_finite) {  // each frame against the DRR at the result: what catches swapped views
    for (std::size_t v = 0; v < views; ++v) {
      const tracking::PixelWindow& w = p.roi_windows[v];
      Image<float> drr(w.rows, w.cols);
      Image<unsigned char> valid(w.rows, w.cols);
      tracking::RenderExtras extras;
      extras.valid = valid.view();
      LFTRACK_RETURN_IF_ERROR(renderer.render(result.T_room_from_ct, p.scene.detectors[v].view, w, drr.view(), &extras));
      in.check_ncc[v] = masked_ncc(frames.line_integral[v].view(), frames.valid[v].view(), drr.view(), valid.view());
    }
    in.has_check_ncc = true;
  }
  return in;
}

Result<std::unique_ptr<RegistrationJudge>> RegistrationJudge::create(
    const PreparedScene& scene, std::shared_ptr<const tracking::DrrRenderer> renderer, const RegistrationSpec& spec,
    std::vector<tracking::DetectorCorrection> corrections, const VerdictLimits& limits, tracking::ThreadPool* pool,
    ViewCheck view_check) {
  if (!renderer) return invalid_argument("registration judge: no renderer");
  if (corrections.size() != scene.scene.detectors.size())
    return invalid_argument("registration judge: one detector correction per detector");
  if (static_cast<int>(scene.scene.detectors.size()) > kMaxVerdictViews)
    return invalid_argument("more views than the verdict holds");
  auto registration = make_scene_registration(scene, renderer, spec, pool);
  if (!registration.ok()) return registration.status();
  std::unique_ptr<RegistrationJudge> judge(new RegistrationJudge);
  judge->scene_ = &scene;
  judge->renderer_ = std::move(renderer);
  judge->registration_ = std::move(registration).value();
  judge->corrections_ = std::move(corrections);
  judge->limits_ = limits;
  judge->view_check_ = view_check;
  if (judges_view_shift(limits)) {
    auto plan = tracking::registration_plan(scene.scene.loop.track_plan);
    if (!plan.ok()) return plan.status().with_context("the view check's plan (loop.track_plan)");
    auto agreement = make_scene_view_agreement(scene, judge->renderer_, spec, *plan, pool);
    if (!agreement.ok()) return agreement.status();
    judge->agreement_ = std::move(agreement).value();
  }
  return judge;
}

Result<JudgedRegistration> RegistrationJudge::judge(const std::vector<Image<std::uint16_t>>& raw,
                                                    const tracking::Pose& start,
                                                    const tracking::RegistrationPlan& plan,
                                                    const BeforeRun& before_run) {
  const PreparedScene& p = *scene_;
  if (raw.size() != p.scene.detectors.size()) return invalid_argument("registration judge: one frame per detector");
  JudgedRegistration out;
  out.input.views = static_cast<int>(raw.size());
  out.quality.resize(raw.size());
  bool quality_ok = true;
  for (std::size_t v = 0; v < raw.size(); ++v) {
    out.input.image_quality[v] = tracking::assess_frame_quality(raw[v].view(), p.roi_windows[v], corrections_[v],
                                                                tracking::FrameQualityLimits{}, &out.quality[v]);
    quality_ok = quality_ok && out.input.image_quality[v] == tracking::FrameQualityIssue::kOk;
  }
  if (!quality_ok) {  // such frames are not registered (frame_quality.hpp), here as in the loop
    out.verdict = judge_registration(limits_, out.input);
    return out;
  }
  auto frames = preprocess_scene_frames(p, raw, corrections_);
  if (!frames.ok()) return frames.status();
  LFTRACK_RETURN_IF_ERROR(registration_->set_frames(frames->frames(), frames->masks()));
  if (before_run) LFTRACK_RETURN_IF_ERROR(before_run(*frames, registration_.get()));
  auto result = registration_->run(start, plan);
  if (!result.ok()) return result.status();
  out.registered = true;
  out.result = std::move(result).value();

  std::vector<tracking::FrameQualityIssue> issues(out.input.image_quality.begin(),
                                                  out.input.image_quality.begin() + out.input.views);
  auto input = verdict_input_of(p, *renderer_, *frames, issues, out.result);
  if (!input.ok()) return input.status();
  out.input = *input;
  out.verdict = judge_registration(limits_, out.input);
  const bool check_views = agreement_ && out.input.pose_finite &&
                           (view_check_ == ViewCheck::kAlways || out.verdict.ok);
  if (check_views) {
    const auto started = std::chrono::steady_clock::now();
    LFTRACK_RETURN_IF_ERROR(agreement_->set_frames(frames->frames(), frames->masks()));
    bool complete = true;
    LFTRACK_RETURN_IF_ERROR(
        agreement_->measure(out.result.T_room_from_ct, 1e12, &out.input.view_shift_mm, &complete));
    out.input.has_view_shift = true;
    out.view_check_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - started).count();
    out.verdict = judge_registration(limits_, out.input);
  }
  return out;
}

}  // namespace lftrack::session
