// The registration verdict (registration_verdict.hpp): one pure check of a result and the
// per-measure floors it compares with. What a scene expects (its limits, its observable
// directions) is the session's (scene_verdict.cpp).

#include "lftrack/loop/registration_verdict.hpp"

#include "lftrack/tracking/correlation_sums.hpp"

#include <cmath>
#include <cstdio>

namespace lftrack::loop {
namespace {

// Per-measure floors, measured with `lftrack register` (10000 photons per pixel, 12 bits) on
// builtin:phantom (light-field renderer; seeds 1, 7, 11 at gold poses up to 4 mm / 2 deg) and on
// scenes/lumbar-ct.yaml (the real CT, Siddon; seeds 1, 7): the lowest view of a good pair
// against the highest view of garbage: uniform noise 0..4095, and the good pair with A and B
// swapped. All-zero and saturated frames are refused earlier by the image-quality gate (they
// register at the no-information value: mi 0, nmi 1, ncc/gc -1, pi 0, gd 0).
//
//   measure  good, lowest view          noise, highest     swapped, highest        floor
//            phantom   lumbar CT        phantom  lumbar    phantom  lumbar
//   mi       1.354     0.632            0.026    0.025     0.407    0.366          0.3
//   nmi      1.229     1.123            1.004    1.004     1.060    1.069          1.04
//   ncc      0.968     0.836            0.007    0.008     0.552    0.684          0.76
//   gc       0.269     0.113            0.005    0.007     0.263    0.034          0.05
//   pi       0.303     (not run)        0.129    (not run) 0.266    (not run)      0.16
//   gd       1.353     (not run)        1.429    (not run) 1.350    (not run)      0.5
//   rncc     0.998     0.998            0.283    0.274     0.655    0.966          0.76
//
// rncc was measured on 2026-11-30 with the simulator of that day (`lftrack register --frames` of
// `--save-frames` pairs, gold 2,-1,1.5,1,-0.5,1), beside ncc on the same frames: ncc good 0.996 /
// 0.995, noise 0.011 / 0.012, swapped 0.461 / 0.917. Its weights favour the pixels where the two
// images happen to agree, so unrelated images score about 0.27, not 0: that is its no-information
// value for the views' agreement, as pi's 0.13 is. Its floor is ncc's, between noise and good
// frames with a wide margin on both sides.
// The floor sits between good frames and noise with a margin on both sides (about half the lowest
// good value's excess over the no-information value). It does not separate swapped frames for
// mi, nmi, gc, pi or gd (a mirrored spine still scores like a plausible registration), nor noise
// for gd (its least-squares intensity scale makes noise score higher than anatomy). What does:
// the NCC of each frame against the DRR at the result (VerdictLimits::min_check_ncc = 0.76:
// good 0.836 and above, swapped 0.684 and below at NCC's own optimum, noise about 0; swapped
// phantom frames exposed everywhere: mi 0.60 / check NCC 0.49, gc 0.25 at 4.6 deg / 0.25), and the
// pose envelope (the lumbar CT's swapped pairs end 9 to 18 mm or 8 to 9 deg off, outside it).
constexpr SimilarityExpectation kExpectations[] = {
    {"mi", 0.3, 0.0},  {"nmi", 1.04, 1.0}, {"ncc", 0.76, 0.0}, {"rncc", 0.76, 0.27},
    {"gc", 0.05, 0.0}, {"pi", 0.16, 0.13},  {"gd", 0.5, 0.0},
};

bool finite_delta(const tracking::Vector6d& d) {
  for (int i = 0; i < 6; ++i)
    if (!std::isfinite(d[i])) return false;
  return true;
}

RegistrationVerdict fail(VerdictReason reason, int view = -1) {
  RegistrationVerdict v;
  v.ok = false;
  v.reason = reason;
  v.view = view;
  return v;
}

RegistrationVerdict compared(VerdictReason reason, int view, int axis, double value, double limit,
                             const char* units) {
  RegistrationVerdict v = fail(reason, view);
  v.axis = axis;
  v.value = value;
  v.limit = limit;
  v.units = units;
  return v;
}

}  // namespace

const char* to_string(VerdictReason reason) {
  switch (reason) {
    case VerdictReason::kOk:
      return "ok";
    case VerdictReason::kNoResult:
      return "no registration result";
    case VerdictReason::kBadViewCount:
      return "no views, or more than the verdict holds";
    case VerdictReason::kImageQuality:
      return "image quality";
    case VerdictReason::kNonFinite:
      return "no finite result";
    case VerdictReason::kLowSimilarity:
      return "similarity below what the scene expects";
    case VerdictReason::kViewsDisagree:
      return "views disagree";
    case VerdictReason::kOutsideEnvelope:
      return "outside the pose envelope";
    case VerdictReason::kEnvelopeEdge:
      return "at the pose envelope's edge";
    case VerdictReason::kViewsPullApart:
      return "a view alone moves the target";
  }
  return "unknown";
}

RegistrationVerdict judge_registration(const VerdictLimits& limits, const VerdictInput& in) {
  if (in.views < 1 || in.views > kMaxVerdictViews) return fail(VerdictReason::kBadViewCount);
  const int n = in.views;
  for (int v = 0; v < n; ++v) {
    if (in.image_quality[v] != tracking::FrameQualityIssue::kOk) {
      RegistrationVerdict r = fail(VerdictReason::kImageQuality, v);
      r.quality_issue = in.image_quality[v];
      return r;
    }
  }
  if (in.stop == tracking::OptimizerStop::kNonFinite || !in.pose_finite || !finite_delta(in.delta_from_nominal))
    return fail(VerdictReason::kNonFinite);
  for (int v = 0; v < n; ++v)
    if (!std::isfinite(in.similarity[v]) || (in.has_check_ncc && !std::isfinite(in.check_ncc[v])) ||
        (in.has_view_shift && !std::isfinite(in.view_shift_mm[v])))
      return fail(VerdictReason::kNonFinite, v);

  // Written so that a NaN limit fails too.
  for (int v = 0; v < n; ++v)
    if (!(in.similarity[v] >= limits.min_similarity))
      return compared(VerdictReason::kLowSimilarity, v, -1, in.similarity[v], limits.min_similarity,
                      limits.measure);
  if (in.has_check_ncc)
    for (int v = 0; v < n; ++v)
      if (!(in.check_ncc[v] >= limits.min_check_ncc))
        return compared(VerdictReason::kLowSimilarity, v, -1, in.check_ncc[v], limits.min_check_ncc, "ncc");

  double best = -std::numeric_limits<double>::infinity();
  for (int v = 0; v < n; ++v) best = std::max(best, in.similarity[v] - limits.no_information_similarity);
  if (best > 0) {
    for (int v = 0; v < n; ++v) {
      const double ratio = (in.similarity[v] - limits.no_information_similarity) / best;
      if (!(ratio >= limits.min_view_ratio))
        return compared(VerdictReason::kViewsDisagree, v, -1, ratio, limits.min_view_ratio, "ratio");
    }
  }

  const double max_t = limits.envelope.translation_mm * (1 + 1e-9) + 1e-9;
  const double max_r_deg = limits.envelope.rotation_deg * (1 + 1e-9) + 1e-9;
  for (int a = 0; a < 3; ++a) {
    const double t = std::abs(in.delta_from_nominal[a]);
    if (!(t <= max_t))
      return compared(VerdictReason::kOutsideEnvelope, -1, a, t, limits.envelope.translation_mm, "mm");
    const double r_deg = tracking::rad_to_deg(std::abs(in.delta_from_nominal[3 + a]));
    if (!(r_deg <= max_r_deg))
      return compared(VerdictReason::kOutsideEnvelope, -1, 3 + a, r_deg, limits.envelope.rotation_deg, "deg");
  }
  // The edge band: inside the envelope, but not by the margin the scene asks (a NaN margin refuses).
  const double edge_t = limits.envelope.translation_mm - limits.envelope_edge_mm;
  const double edge_r_deg = limits.envelope.rotation_deg - limits.envelope_edge_deg;
  for (int a = 0; a < 3; ++a) {
    const double t = std::abs(in.delta_from_nominal[a]);
    if (limits.envelope_edge_mm != 0 && !(t <= edge_t))
      return compared(VerdictReason::kEnvelopeEdge, -1, a, t, edge_t, "mm");
    const double r_deg = tracking::rad_to_deg(std::abs(in.delta_from_nominal[3 + a]));
    if (limits.envelope_edge_deg != 0 && !(r_deg <= edge_r_deg))
      return compared(VerdictReason::kEnvelopeEdge, -1, 3 + a, r_deg, edge_r_deg, "deg");
  }
  if (in.has_view_shift)
    for (int v = 0; v < n; ++v)
      if (!(in.view_shift_mm[v] <= limits.max_view_shift_mm))
        return compared(VerdictReason::kViewsPullApart, v, -1, in.view_shift_mm[v], limits.max_view_shift_mm, "mm");
  RegistrationVerdict ok;
  ok.ok = true;
  ok.reason = VerdictReason::kOk;
  return ok;
}

double masked_ncc(const tracking::ImageView<const float>& a, const tracking::ImageView<const unsigned char>& a_valid,
                  const tracking::ImageView<const float>& b, const tracking::ImageView<const unsigned char>& b_valid) {
  if (a.rows != b.rows || a.cols != b.cols) return -2;
  const bool am = !a_valid.empty(), bm = !b_valid.empty();
  if ((am && (a_valid.rows != a.rows || a_valid.cols != a.cols)) ||
      (bm && (b_valid.rows != b.rows || b_valid.cols != b.cols)))
    return -2;
  tracking::CorrelationSums sums;
  for (int r = 0; r < a.rows; ++r)
    for (int c = 0; c < a.cols; ++c) {
      if ((am && !a_valid.at(r, c)) || (bm && !b_valid.at(r, c))) continue;
      const double x = a.at(r, c), y = b.at(r, c);
      if (std::isfinite(x) && std::isfinite(y)) sums.add(x, y);
    }
  return sums.n < 16 ? 0 : sums.value();
}

Result<SimilarityExpectation> similarity_expectation(const std::string& measure) {
  for (const auto& e : kExpectations)
    if (measure == e.measure) return e;
  return invalid_argument("no similarity expectation for measure '" + measure + "'");
}

std::string verdict_text(const RegistrationVerdict& v, const std::vector<std::string>& view_names) {
  if (v.ok) return "ACCEPTED";
  std::string text = std::string("REJECTED — ") + to_string(v.reason);
  const std::string view = v.view >= 0 && v.view < static_cast<int>(view_names.size())
                               ? view_names[static_cast<std::size_t>(v.view)]
                               : std::to_string(v.view);
  char detail[160] = "";
  static const char* const kAxes[] = {"tx", "ty", "tz", "rx", "ry", "rz"};
  switch (v.reason) {
    case VerdictReason::kImageQuality:
      std::snprintf(detail, sizeof detail, " (view %s: %s frame)", view.c_str(), tracking::to_string(v.quality_issue));
      break;
    case VerdictReason::kNonFinite:
      if (v.view >= 0) std::snprintf(detail, sizeof detail, " (view %s: similarity not finite)", view.c_str());
      break;
    case VerdictReason::kLowSimilarity:
      std::snprintf(detail, sizeof detail, " (view %s: %s %.4f < %.4f expected)", view.c_str(), v.units, v.value,
                    v.limit);
      break;
    case VerdictReason::kViewsDisagree:
      std::snprintf(detail, sizeof detail, " (view %s: %.3f of the best view's similarity < %.3f)", view.c_str(),
                    v.value, v.limit);
      break;
    case VerdictReason::kOutsideEnvelope:
      std::snprintf(detail, sizeof detail, " (|%s| %.3f %s > %.3f %s)", kAxes[v.axis >= 0 && v.axis < 6 ? v.axis : 0],
                    v.value, v.units, v.limit, v.units);
      break;
    case VerdictReason::kEnvelopeEdge:
      std::snprintf(detail, sizeof detail, " (|%s| %.3f %s > %.3f %s, the envelope less its edge band)",
                    kAxes[v.axis >= 0 && v.axis < 6 ? v.axis : 0], v.value, v.units, v.limit, v.units);
      break;
    case VerdictReason::kViewsPullApart:
      std::snprintf(detail, sizeof detail, " (view %s registered alone moves the target %.3g mm across it > %.3g mm)",
                    view.c_str(), v.value, v.limit);
      break;
    default:
      break;
  }
  return text + detail;
}

}  // namespace lftrack::loop
