// The registration verdict, table-tested: every reason, its boundary, the per-measure limits and
// the single-view rule.

#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/session/scene_verdict.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>

#include "lftrack/tracking/similarity.hpp"

namespace lftrack::session {

using loop::judge_registration;
using loop::judges_view_shift;
using loop::masked_ncc;
using loop::RegistrationVerdict;
using loop::similarity_expectation;
using loop::verdict_text;
using loop::VerdictInput;
using loop::VerdictLimits;
using loop::VerdictReason;
namespace {

const double kNan = std::numeric_limits<double>::quiet_NaN();
const double kInf = std::numeric_limits<double>::infinity();

VerdictLimits mi_limits() {
  VerdictLimits l;
  l.measure = "mi";
  l.min_similarity = 0.4;
  l.no_information_similarity = 0;
  l.min_view_ratio = 0.5;
  l.min_check_ncc = 0.76;
  l.envelope.translation_mm = 10;
  l.envelope.rotation_deg = 5;
  return l;
}

VerdictInput good_input() {
  VerdictInput in;
  in.views = 2;
  in.pose_finite = true;
  in.similarity = {1.45, 1.35, 0, 0};
  in.has_check_ncc = true;
  in.check_ncc = {0.97, 0.96, 0, 0};
  in.delta_from_nominal << 2.0, -1.0, 1.5, 0.017, 0.009, -0.017;
  return in;
}

struct VerdictCase {
  const char* name;
  std::function<void(VerdictInput&)> change;
  VerdictReason reason;
  int view = -1;
  int axis = -1;
};

const double kDeg = M_PI / 180;

const std::vector<VerdictCase> kCases = {
    {"AllGood", [](VerdictInput&) {}, VerdictReason::kOk},
    {"NoViews", [](VerdictInput& in) { in.views = 0; }, VerdictReason::kBadViewCount},
    {"FiveViews", [](VerdictInput& in) { in.views = 5; }, VerdictReason::kBadViewCount},
    {"DeadFrameInB",
     [](VerdictInput& in) { in.image_quality[1] = tracking::FrameQualityIssue::kDeadPixels; },
     VerdictReason::kImageQuality, 1},
    {"SaturatedFrameInA",
     [](VerdictInput& in) { in.image_quality[0] = tracking::FrameQualityIssue::kSaturated; },
     VerdictReason::kImageQuality, 0},
    {"ImageQualityComesFirst",
     [](VerdictInput& in) {
       in.image_quality[0] = tracking::FrameQualityIssue::kBlank;
       in.pose_finite = false;
       in.similarity[1] = kNan;
     },
     VerdictReason::kImageQuality, 0},
    {"NoFiniteCost", [](VerdictInput& in) { in.stop = tracking::OptimizerStop::kNonFinite; },
     VerdictReason::kNonFinite},
    {"NanPose", [](VerdictInput& in) { in.pose_finite = false; }, VerdictReason::kNonFinite},
    {"NanInDelta", [](VerdictInput& in) { in.delta_from_nominal(4) = kNan; }, VerdictReason::kNonFinite},
    {"InfInDelta", [](VerdictInput& in) { in.delta_from_nominal(0) = kInf; }, VerdictReason::kNonFinite},
    {"NanSimilarity", [](VerdictInput& in) { in.similarity[1] = kNan; }, VerdictReason::kNonFinite, 1},
    {"NanCheckNcc", [](VerdictInput& in) { in.check_ncc[0] = kNan; }, VerdictReason::kNonFinite, 0},
    {"NanCheckNccNotGivenIsNotLookedAt",
     [](VerdictInput& in) {
       in.has_check_ncc = false;
       in.check_ncc[0] = kNan;
     },
     VerdictReason::kOk},
    {"BudgetStopsAreNotFailures", [](VerdictInput& in) { in.stop = tracking::OptimizerStop::kTimeBudget; },
     VerdictReason::kOk},
    {"BlankPairAtZeroMi", [](VerdictInput& in) { in.similarity = {0.0, 0.0, 0, 0}; }, VerdictReason::kLowSimilarity,
     0},
    {"LowSimilarityInB", [](VerdictInput& in) { in.similarity[1] = 0.39; }, VerdictReason::kLowSimilarity, 1},
    {"SimilarityAtTheFloorPasses",
     [](VerdictInput& in) { in.similarity = {0.4, 0.4, 0, 0}; }, VerdictReason::kOk},
    {"LowCheckNccInA", [](VerdictInput& in) { in.check_ncc[0] = 0.55; }, VerdictReason::kLowSimilarity, 0},
    {"CheckNccAtTheFloorPasses", [](VerdictInput& in) { in.check_ncc[1] = 0.76; }, VerdictReason::kOk},
    {"ViewsDisagree", [](VerdictInput& in) { in.similarity = {1.5, 0.7, 0, 0}; }, VerdictReason::kViewsDisagree,
     1},
    {"ViewsAtTheRatioAgree", [](VerdictInput& in) { in.similarity = {1.6, 0.8, 0, 0}; }, VerdictReason::kOk},
    {"TranslationOutside", [](VerdictInput& in) { in.delta_from_nominal(1) = -10.01; },
     VerdictReason::kOutsideEnvelope, -1, 1},
    {"TranslationAtTheEdgePasses", [](VerdictInput& in) { in.delta_from_nominal(2) = 10.0; }, VerdictReason::kOk},
    {"RotationOutside", [](VerdictInput& in) { in.delta_from_nominal(5) = 5.01 * kDeg; },
     VerdictReason::kOutsideEnvelope, -1, 5},
    {"RotationAtTheEdgePasses", [](VerdictInput& in) { in.delta_from_nominal(3) = -5.0 * kDeg; },
     VerdictReason::kOk},
    {"OneViewJudgesOnlyItsOwn",
     [](VerdictInput& in) {
       in.views = 1;
       in.similarity[1] = kNan;
       in.image_quality[1] = tracking::FrameQualityIssue::kBlank;
     },
     VerdictReason::kOk},
};

class VerdictTable : public ::testing::TestWithParam<VerdictCase> {};

TEST_P(VerdictTable, GivesTheReasonAndTheViewOrAxis) {
  VerdictInput in = good_input();
  GetParam().change(in);
  const RegistrationVerdict v = judge_registration(mi_limits(), in);
  EXPECT_EQ(v.reason, GetParam().reason) << to_string(v.reason);
  EXPECT_EQ(v.ok, GetParam().reason == VerdictReason::kOk);
  EXPECT_EQ(v.view, GetParam().view);
  EXPECT_EQ(v.axis, GetParam().axis);
}

INSTANTIATE_TEST_SUITE_P(RegistrationVerdict, VerdictTable, ::testing::ValuesIn(kCases),
                         [](const ::testing::TestParamInfo<VerdictCase>& p) { return std::string(p.param.name); });

TEST(RegistrationVerdict, ADefaultInputFails) {
  EXPECT_FALSE(judge_registration(mi_limits(), VerdictInput{}).ok);
  VerdictInput in;
  in.views = 2;
  EXPECT_EQ(judge_registration(mi_limits(), in).reason, VerdictReason::kNonFinite) << "pose_finite is not assumed";
  EXPECT_FALSE(RegistrationVerdict{}.ok);
}

TEST(RegistrationVerdict, ReportsTheNumbersCompared) {
  VerdictInput in = good_input();
  in.similarity[1] = 0.012;
  const RegistrationVerdict low = judge_registration(mi_limits(), in);
  EXPECT_DOUBLE_EQ(low.value, 0.012);
  EXPECT_DOUBLE_EQ(low.limit, 0.4);
  EXPECT_STREQ(low.units, "mi");
  EXPECT_EQ(verdict_text(low, {"A", "B"}),
            "REJECTED — similarity below what the scene expects (view B: mi 0.0120 < 0.4000 expected)");

  in = good_input();
  in.delta_from_nominal(4) = -6 * kDeg;
  const RegistrationVerdict out = judge_registration(mi_limits(), in);
  EXPECT_NEAR(out.value, 6.0, 1e-9);
  EXPECT_DOUBLE_EQ(out.limit, 5.0);
  EXPECT_STREQ(out.units, "deg");
  EXPECT_NE(verdict_text(out, {"A", "B"}).find("|ry| 6.000 deg > 5.000 deg"), std::string::npos);

  in = good_input();
  in.image_quality[0] = tracking::FrameQualityIssue::kSaturated;
  const RegistrationVerdict quality = judge_registration(mi_limits(), in);
  EXPECT_EQ(quality.quality_issue, tracking::FrameQualityIssue::kSaturated);
  EXPECT_TRUE(std::isnan(quality.value));
  EXPECT_NE(verdict_text(quality, {"A", "B"}).find("view A"), std::string::npos);
  EXPECT_EQ(verdict_text(judge_registration(mi_limits(), good_input()), {"A", "B"}), "ACCEPTED");
}

TEST(RegistrationVerdict, ANanLimitRejectsInsteadOfPassingEverything) {
  VerdictLimits l = mi_limits();
  l.min_similarity = kNan;
  EXPECT_EQ(judge_registration(l, good_input()).reason, VerdictReason::kLowSimilarity);
  l = mi_limits();
  l.envelope.translation_mm = kNan;
  EXPECT_EQ(judge_registration(l, good_input()).reason, VerdictReason::kOutsideEnvelope);
}

TEST(RegistrationVerdict, AgreementIsMeasuredAboveTheNoInformationValue) {
  // nmi: unrelated images score 1, so 1.25 and 1.12 are excesses of 0.25 and 0.12 (ratio 0.48).
  VerdictLimits l = mi_limits();
  l.measure = "nmi";
  l.min_similarity = 1.1;
  l.no_information_similarity = 1.0;
  VerdictInput in = good_input();
  in.similarity = {1.25, 1.12, 0, 0};
  EXPECT_EQ(judge_registration(l, in).reason, VerdictReason::kViewsDisagree);
  in.similarity = {1.25, 1.20, 0, 0};
  EXPECT_TRUE(judge_registration(l, in).ok);
}

VerdictLimits with_checks() {
  VerdictLimits l = mi_limits();
  l.envelope_edge_mm = 0.5;
  l.envelope_edge_deg = 1.0;
  l.max_view_shift_mm = 1.0;
  return l;
}

VerdictInput with_shifts(double a_mm, double b_mm) {
  VerdictInput in = good_input();
  in.has_view_shift = true;
  in.view_shift_mm = {a_mm, b_mm, 0, 0};
  return in;
}

TEST(RegistrationVerdictEdge, AResultInTheEdgeBandIsRefusedWithItsAxis) {
  VerdictInput in = good_input();
  in.delta_from_nominal(2) = -9.6;  // inside the envelope (10 mm), within 0.5 mm of its limit
  const RegistrationVerdict edge = judge_registration(with_checks(), in);
  EXPECT_EQ(edge.reason, VerdictReason::kEnvelopeEdge);
  EXPECT_EQ(edge.axis, 2);
  EXPECT_NEAR(edge.value, 9.6, 1e-12);
  EXPECT_DOUBLE_EQ(edge.limit, 9.5);
  EXPECT_NE(verdict_text(edge, {"A", "B"}).find("|tz| 9.600 mm > 9.500 mm, the envelope less its edge band"),
            std::string::npos)
      << verdict_text(edge, {"A", "B"});
  in.delta_from_nominal(2) = -9.5;
  EXPECT_TRUE(judge_registration(with_checks(), in).ok) << "the band's inner limit itself passes";
  in.delta_from_nominal(2) = 0;
  in.delta_from_nominal(4) = 4.2 * kDeg;
  const RegistrationVerdict rot = judge_registration(with_checks(), in);
  EXPECT_EQ(rot.reason, VerdictReason::kEnvelopeEdge);
  EXPECT_EQ(rot.axis, 4);
  EXPECT_STREQ(rot.units, "deg");
  // Beyond the envelope is still "outside", not "at the edge"; without a band the edge passes.
  in.delta_from_nominal(4) = 5.5 * kDeg;
  EXPECT_EQ(judge_registration(with_checks(), in).reason, VerdictReason::kOutsideEnvelope);
  in.delta_from_nominal(4) = 4.9 * kDeg;
  EXPECT_TRUE(judge_registration(mi_limits(), in).ok);
}

TEST(RegistrationVerdictEdge, ANanBandRefuses) {
  VerdictLimits l = with_checks();
  l.envelope_edge_mm = kNan;
  EXPECT_EQ(judge_registration(l, good_input()).reason, VerdictReason::kEnvelopeEdge);
}

TEST(RegistrationVerdictViews, AViewThatAloneMovesTheTargetIsRefused) {
  EXPECT_TRUE(judge_registration(with_checks(), with_shifts(0.2, 0.99)).ok);
  const RegistrationVerdict pulled = judge_registration(with_checks(), with_shifts(0.2, 1.6));
  EXPECT_EQ(pulled.reason, VerdictReason::kViewsPullApart);
  EXPECT_EQ(pulled.view, 1);
  EXPECT_DOUBLE_EQ(pulled.value, 1.6);
  EXPECT_NE(verdict_text(pulled, {"A", "B"}).find("view B registered alone moves the target 1.6 mm across it > 1 mm"),
            std::string::npos)
      << verdict_text(pulled, {"A", "B"});
  // Shifts not given are not judged; limits without a view check never look at them.
  VerdictInput not_given = with_shifts(5, 5);
  not_given.has_view_shift = false;
  EXPECT_TRUE(judge_registration(with_checks(), not_given).ok);
  EXPECT_TRUE(judge_registration(mi_limits(), with_shifts(5, 5)).ok);
  EXPECT_FALSE(judges_view_shift(mi_limits()));
  EXPECT_TRUE(judges_view_shift(with_checks()));
}

TEST(RegistrationVerdictViews, ANonFiniteShiftIsNoResultAndTheCheapChecksComeFirst) {
  const RegistrationVerdict nan = judge_registration(with_checks(), with_shifts(kNan, 0.1));
  EXPECT_EQ(nan.reason, VerdictReason::kNonFinite);
  EXPECT_EQ(nan.view, 0);
  VerdictInput low = with_shifts(3, 3);
  low.similarity[0] = 0.1;
  EXPECT_EQ(judge_registration(with_checks(), low).reason, VerdictReason::kLowSimilarity);
  VerdictLimits l = with_checks();
  l.max_view_shift_mm = kNan;
  EXPECT_EQ(judge_registration(l, with_shifts(0.1, 0.1)).reason, VerdictReason::kViewsPullApart)
      << "a NaN limit refuses";
}

Scene scene_from(const std::string& text) {
  auto scene = parse_scene(text, "test.yaml", ".");
  EXPECT_TRUE(scene.ok()) << scene.status().message();
  return scene.ok() ? *scene : Scene{};
}

TEST(RegistrationVerdictLimits, EveryMeasureHasADefaultFloorAboveItsNoInformationValue) {
  const Scene scene = *load_scene(kBuiltinPhantom);
  for (const auto& measure : tracking::similarity_names()) {
    auto l = verdict_limits(scene, measure);
    ASSERT_TRUE(l.ok()) << measure;
    EXPECT_EQ(std::string(l->measure), measure);
    EXPECT_GT(l->min_similarity, l->no_information_similarity) << measure;
    EXPECT_DOUBLE_EQ(l->envelope.translation_mm, scene.envelope.translation_mm);
    EXPECT_DOUBLE_EQ(l->envelope.rotation_deg, scene.envelope.rotation_deg);
  }
  EXPECT_FALSE(verdict_limits(scene, "magic").ok());
  // Different scales: the floors differ per measure.
  EXPECT_NE(verdict_limits(scene, "mi")->min_similarity, verdict_limits(scene, "nmi")->min_similarity);
  EXPECT_GT(verdict_limits(scene, "nmi")->min_similarity, 1.0);
}

TEST(RegistrationVerdictLimits, ASceneFloorAppliesToItsOwnMeasureOnly) {
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  const Scene defaults = scene_from(text);
  EXPECT_FALSE(defaults.min_similarity_given);
  const std::string safety = "safety:\n";
  text.replace(text.find(safety), safety.size(), "safety:\n  min_similarity: 0.9\n");
  const Scene scene = scene_from(text);
  EXPECT_TRUE(scene.min_similarity_given);
  EXPECT_DOUBLE_EQ(verdict_limits(scene, "mi")->min_similarity, 0.9) << "the scene's measure is mi";
  EXPECT_DOUBLE_EQ(verdict_limits(scene, "ncc")->min_similarity, similarity_expectation("ncc")->min_similarity)
      << "0.9 is in mi's units; ncc keeps its own default";
}

TEST(RegistrationVerdict, MaskedNccIsPearsonOverThePixelsBothMasksKeep) {
  tracking::Image<float> a(4, 5), b(4, 5);
  tracking::Image<unsigned char> mask(4, 5);
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 5; ++c) {
      a.at(r, c) = static_cast<float>(r * 5 + c);
      b.at(r, c) = 3.0f * a.at(r, c) + 1.0f;
      mask.at(r, c) = 1;
    }
  EXPECT_NEAR(masked_ncc(a.view(), {}, b.view(), {}), 1.0, 1e-12);
  b.at(0, 0) = 1000;
  mask.at(0, 0) = 0;
  EXPECT_LT(masked_ncc(a.view(), {}, b.view(), {}), 0.9);
  EXPECT_NEAR(masked_ncc(a.view(), mask.view(), b.view(), {}), 1.0, 1e-12) << "the outlier is masked";
  b.at(1, 1) = std::numeric_limits<float>::quiet_NaN();
  EXPECT_NEAR(masked_ncc(a.view(), mask.view(), b.view(), {}), 1.0, 1e-12) << "a NaN pixel is skipped";
  tracking::Image<float> constant(4, 5);
  EXPECT_EQ(masked_ncc(a.view(), {}, constant.view(), {}), 0.0);
  tracking::Image<float> other(3, 5);
  EXPECT_EQ(masked_ncc(a.view(), {}, other.view(), {}), -2.0);
}

// A one-detector scene: the built-in phantom without detector B.
std::string one_detector_text(bool single_view) {
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  const auto b = text.find("  - name: B");
  const auto envelope = text.find("envelope:");
  text.erase(b, envelope - b);
  if (single_view) {
    const std::string tracking = "tracking:\n";
    text.replace(text.find(tracking), tracking.size(), "tracking:\n  single_view: true\n");
  }
  return text;
}

TEST(SingleView, OneDetectorIsRefusedUnlessTheSceneSaysSo) {
  const Scene one = scene_from(one_detector_text(false));
  ASSERT_EQ(one.detectors.size(), 1u);
  const Status refused = check_views_observable(one);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.message().find("single view cannot see depth"), std::string::npos) << refused.message();
  EXPECT_NE(refused.message().find("single_view: true"), std::string::npos) << refused.message();
  EXPECT_NE(refused.message().find("(-0.707, 0.707, 0.000)"), std::string::npos) << refused.message();

  const Scene allowed = scene_from(one_detector_text(true));
  EXPECT_TRUE(allowed.registration.single_view);
  EXPECT_TRUE(check_views_observable(allowed).ok());
  const auto d = unobservable_direction_room(allowed);
  ASSERT_TRUE(d.has_value());
  // Detector A's source sits up and to the patient's left along (0.707, -0.707, 0) from the
  // isocentre: its central ray runs the other way.
  EXPECT_NEAR(d->x(), -M_SQRT1_2, 1e-9);
  EXPECT_NEAR(d->y(), M_SQRT1_2, 1e-9);
  EXPECT_NEAR(d->z(), 0.0, 1e-9);
  EXPECT_NEAR(d->norm(), 1.0, 1e-12);

  const Scene two = *load_scene(kBuiltinPhantom);
  EXPECT_TRUE(check_views_observable(two).ok());
  EXPECT_FALSE(unobservable_direction_room(two).has_value());
}

TEST(SingleView, TheKeyIsABoolean) {
  std::string text = one_detector_text(true);
  text.replace(text.find("single_view: true"), std::string("single_view: true").size(), "single_view: yes please");
  auto scene = parse_scene(text, "test.yaml", ".");
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("tracking.single_view must be true or false"), std::string::npos);
}

}  // namespace
}  // namespace lftrack::session
