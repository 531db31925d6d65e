#pragma once
// The registration verdict: is one registration result fit to be used? One pure function that
// `lftrack register` and the loop's safety gate share. It checks, in this order, and reports the
// first failure:
//
//   image quality    every frame passed the image-quality gate (frame_quality.hpp), run on the
//                    raw frame over its ROI window exactly as the loop does
//   non-finite       the optimizer found a finite cost (stop is not kNonFinite), and the pose and
//                    every view's similarity are finite
//   low similarity   every view's similarity at the result reaches the measure's absolute floor
//                    (what the scene expects of a registered pair: safety.min_similarity, or the
//                    measure's default below); and, when given, every view's NCC of the frame
//                    against the DRR at the result reaches min_check_ncc: a check that does not
//                    depend on the measure optimised (gc and pi score A/B-swapped frames of a
//                    symmetric spine almost as high as the right ones; NCC does not)
//   views disagree   every view's similarity above the measure's no-information value is at
//                    least `min_view_ratio` of the best view's: one view that matches much worse
//                    than the others (a wrong, swapped or partly covered frame)
//   outside envelope the result, as a delta from the nominal pose, lies inside the scene's pose
//                    envelope (light fields only hold the rays of poses inside it; beyond it the
//                    registration has wandered off or the DRRs extrapolate)
//   envelope edge    and not within `envelope_edge_mm` / `envelope_edge_deg` of its limits: a
//                    start beyond the capture range ends wherever the search gave up, often short
//                    of the limit, and commissioning only has evidence for right results up to 0.9
//                    of the envelope (docs/commissioning.md)
//   views pull apart when given (has_view_shift): each view registered alone from the result
//                    moves the target at most `max_view_shift_mm` across that view (the shift
//                    along its ray through the target, which one view cannot see, left out). Two
//                    views that agree on the anatomy leave the joint result where it is; a result
//                    that is a compromise between views that see different things does not hold
//                    in either view alone (view_agreement.hpp)
//
// judge_registration() allocates nothing and takes no lock: the loop calls it every cycle.
// Only at set-up (verdict_limits, check_views_observable, verdict_text) is anything allocated.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/tracking/frame_quality.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/optimizer.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::loop {

inline constexpr int kMaxVerdictViews = 4;

enum class VerdictReason : std::uint8_t {
  kOk = 0,
  kNoResult,         // nothing was judged (the registration returned an error, or no input)
  kBadViewCount,     // views outside 1..kMaxVerdictViews
  kImageQuality,     // a frame failed the image-quality gate; `view`, `quality_issue`
  kNonFinite,        // no finite cost (optimizer stop kNonFinite), a NaN/inf pose or similarity
  kLowSimilarity,    // a view's similarity below the measure's floor; `view`, value < limit
  kViewsDisagree,    // a view's excess similarity is below min_view_ratio of the best view's
  kOutsideEnvelope,  // a delta component outside the envelope; `axis`, |value| > limit
  kEnvelopeEdge,     // a delta component within the edge band of its limit; `axis`, |value| > limit
  kViewsPullApart,   // a view alone moves the target beyond max_view_shift_mm; `view`, value > limit
};
const char* to_string(VerdictReason reason);

// What a registration must reach, resolved once from the scene (verdict_limits) and read every
// cycle. Similarities are in the measure's own units (larger is better, similarity.hpp).
struct VerdictLimits {
  const char* measure = "mi";            // the similarity measure's name (static storage)
  double min_similarity = 0.0;           // absolute floor per view
  double no_information_similarity = 0;  // the measure's value for unrelated images
  // (s_view - no_information) / (s_best - no_information) must reach this, per view.
  double min_view_ratio = 0.5;
  double min_check_ncc = 0.76;  // per view, the NCC of frame and DRR at the result (when given)
  tracking::PoseEnvelope envelope;  // about the nominal pose: |t_i| <= translation_mm, |omega_i| <= rotation_deg
  // The band inside the envelope's limits where a result is refused too (0: none): a result is
  // accepted only while |t_i| <= translation_mm - envelope_edge_mm and |omega_i| <= rotation_deg -
  // envelope_edge_deg.
  double envelope_edge_mm = 0;
  double envelope_edge_deg = 0;
  // The most a view registered alone from the result may move the target across it (when the
  // input has view shifts).
  double max_view_shift_mm = std::numeric_limits<double>::infinity();
};

struct VerdictInput {
  int views = 0;
  // Per view, from tracking::assess_frame_quality on the raw frame over its ROI window.
  std::array<tracking::FrameQualityIssue, kMaxVerdictViews> image_quality{};
  tracking::OptimizerStop stop = tracking::OptimizerStop::kConverged;
  bool pose_finite = false;  // T_room_from_ct is finite (the caller says so; not assumed)
  std::array<double, kMaxVerdictViews> similarity{};  // per view, at the result
  // Per view, the NCC of the preprocessed frame against the DRR at the result (masked_ncc), when
  // has_check_ncc. `lftrack register` always gives it.
  bool has_check_ncc = false;
  std::array<double, kMaxVerdictViews> check_ncc{};
  // The result as a delta from the nominal pose about the registration origin: t [mm], omega
  // (rotation vector) [rad] (tracking::delta_between(nominal, result, origin_room)).
  tracking::Vector6d delta_from_nominal = tracking::Vector6d::Zero();
  // Per view, when has_view_shift: how far that view registered alone from the result moves the
  // target across it, mm at the target (view_agreement.hpp). Judged after everything else.
  bool has_view_shift = false;
  std::array<double, kMaxVerdictViews> view_shift_mm{};
};

struct RegistrationVerdict {
  bool ok = false;
  VerdictReason reason = VerdictReason::kNoResult;
  int view = -1;  // the view at fault (image quality, non-finite similarity, low similarity, disagree, pull apart)
  int axis = -1;  // the delta component at fault (outside envelope, edge): 0..2 t x, y, z; 3..5 omega x, y, z
  tracking::FrameQualityIssue quality_issue = tracking::FrameQualityIssue::kOk;
  // The numbers compared, where a comparison failed: similarity and floor (the measure's units),
  // ratio and min_view_ratio, |component| and envelope ("mm" or "deg"); NaN otherwise.
  double value = std::numeric_limits<double>::quiet_NaN();
  double limit = std::numeric_limits<double>::quiet_NaN();
  const char* units = "";  // static storage: the measure's name, "ratio", "mm" or "deg"
};

// Pure; allocates nothing. A default-constructed input fails (no views, pose not finite).
RegistrationVerdict judge_registration(const VerdictLimits& limits, const VerdictInput& input);

// Whether the limits judge per-view shifts at all (a finite max_view_shift_mm): callers compute
// the shifts (a registration per view) only then, and only for a result everything else passed.
inline bool judges_view_shift(const VerdictLimits& limits) {
  return limits.max_view_shift_mm < std::numeric_limits<double>::infinity();
}

// The normalised cross-correlation of two images of the same size over the pixels where both
// masks (empty: all valid) are 1 and both values are finite; 0 with fewer than 16 such pixels or
// a constant image, -2 for images of different sizes. Allocates nothing.
double masked_ncc(const tracking::ImageView<const float>& a, const tracking::ImageView<const unsigned char>& a_valid,
                  const tracking::ImageView<const float>& b, const tracking::ImageView<const unsigned char>& b_valid);

// Per-measure defaults (measured, see registration_verdict.cpp): the absolute floor and the value
// of unrelated images. Fails for an unknown measure.
struct SimilarityExpectation {
  const char* measure;
  double min_similarity;
  double no_information;
};
Result<SimilarityExpectation> similarity_expectation(const std::string& measure);

// A line for people: "ACCEPTED", or "REJECTED — low similarity (view B: mi 0.012 < 0.350
// expected)". Allocates; not for the cycle.
std::string verdict_text(const RegistrationVerdict& verdict, const std::vector<std::string>& view_names);

}  // namespace lftrack::loop
