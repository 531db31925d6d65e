// The safety gate, table-tested: every rule, its boundary, and the failure counting.

#include "lftrack/loop/safety_gate.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>

namespace lftrack::loop {
namespace {

GateInput good_input() {
  GateInput in;
  in.registration_ok = true;
  in.step << 0.5, -0.3, 0.2, 0.002, 0.0, -0.001;
  in.total << 3.0, -1.0, 2.0, 0.02, 0.01, 0.0;
  in.views = 2;
  in.similarity = {0.62, 0.75, 0, 0};
  in.reference_similarity = {0.65, 0.78, 0, 0};
  in.frame_age_ms = 40;
  in.pair_skew_ms = 2;
  return in;
}

struct GateCase {
  const char* name;
  std::function<void(GateInput&)> change;
  GateDecision decision;
  GateReason reason;
};

const double kNan = std::numeric_limits<double>::quiet_NaN();
const double kInf = std::numeric_limits<double>::infinity();

const std::vector<GateCase> kCases = {
    {"AllGood", [](GateInput&) {}, GateDecision::kApply, GateReason::kOk},
    {"NanInStep", [](GateInput& in) { in.step(1) = kNan; }, GateDecision::kHold, GateReason::kNonFinite},
    {"InfInTotal", [](GateInput& in) { in.total(4) = kInf; }, GateDecision::kHold, GateReason::kNonFinite},
    {"NanSimilarity", [](GateInput& in) { in.similarity[1] = kNan; }, GateDecision::kHold,
     GateReason::kNonFinite},
    {"NanFrameAge", [](GateInput& in) { in.frame_age_ms = kNan; }, GateDecision::kHold,
     GateReason::kNonFinite},
    {"NanEvenWithoutResult",
     [](GateInput& in) {
       in.registration_ok = false;
       in.step(0) = kNan;
     },
     GateDecision::kHold, GateReason::kNonFinite},
    {"StepJustInside", [](GateInput& in) { in.step(0) = 2.0; }, GateDecision::kApply, GateReason::kOk},
    {"StepTranslationTooLarge", [](GateInput& in) { in.step(2) = -2.01; }, GateDecision::kHold,
     GateReason::kStepTooLarge},
    {"StepRotationTooLarge", [](GateInput& in) { in.step(3) = tracking::deg_to_rad(2.1); },
     GateDecision::kHold, GateReason::kStepTooLarge},
    {"SuddenEightMillimetreShift", [](GateInput& in) { in.step(1) = 8.0; }, GateDecision::kHold,
     GateReason::kStepTooLarge},
    {"ApprovedStepSkipsOnlyTheStepLimit",
     [](GateInput& in) {
       in.step(1) = 8.0;
       in.step_approved = true;
     },
     GateDecision::kApply, GateReason::kOk},
    {"ApprovedStepStillRespectsTheTotal",
     [](GateInput& in) {
       in.step(1) = 8.0;
       in.total(1) = 10.5;
       in.step_approved = true;
     },
     GateDecision::kHold, GateReason::kTotalTooLarge},
    {"ApprovedStepStillHoldsOnNan",
     [](GateInput& in) {
       in.step(1) = kNan;
       in.step_approved = true;
     },
     GateDecision::kHold, GateReason::kNonFinite},
    {"TotalTooLarge", [](GateInput& in) { in.total(0) = 10.5; }, GateDecision::kHold,
     GateReason::kTotalTooLarge},
    {"TotalRotationTooLarge", [](GateInput& in) { in.total(5) = tracking::deg_to_rad(5.5); },
     GateDecision::kHold, GateReason::kTotalTooLarge},
    {"ReadbackOff", [](GateInput& in) { in.readback_error_mm = 0.6; }, GateDecision::kHold,
     GateReason::kReadbackMismatch},
    {"ReadbackRotationOff", [](GateInput& in) { in.readback_error_deg = 0.6; }, GateDecision::kHold,
     GateReason::kReadbackMismatch},
    {"NoReadback", [](GateInput& in) { in.readback_valid = false; }, GateDecision::kHold,
     GateReason::kActuatorFault},
    {"CommandRefusedByTheActuator", [](GateInput& in) { in.command_refused = true; }, GateDecision::kHold,
     GateReason::kCommandRefused},
    {"NoReadbackStandsBeforeARefusal",
     [](GateInput& in) {
       in.command_refused = true;
       in.readback_valid = false;
     },
     GateDecision::kHold, GateReason::kActuatorFault},
    {"NoResult", [](GateInput& in) { in.registration_ok = false; }, GateDecision::kSkip,
     GateReason::kNoResult},
    {"RejectedByTheRegistrationVerdict",
     [](GateInput& in) {
       in.registration_ok = false;
       in.registration_failure = GateReason::kOutsideEnvelope;
     },
     GateDecision::kSkip, GateReason::kOutsideEnvelope},
    {"NoReasonGivenIsNoResult",
     [](GateInput& in) {
       in.registration_ok = false;
       in.registration_failure = GateReason::kOk;
     },
     GateDecision::kSkip, GateReason::kNoResult},
    {"NoFrames",
     [](GateInput& in) {
       in.frames_ok = false;
       in.registration_ok = false;
     },
     GateDecision::kSkip, GateReason::kNoFrames},
    {"TwoOverrunsInARowGoOn", [](GateInput& in) { in.consecutive_overruns = 2; }, GateDecision::kApply,
     GateReason::kOk},
    {"ThreeOverrunsInARowHold", [](GateInput& in) { in.consecutive_overruns = 3; }, GateDecision::kHold,
     GateReason::kOverruns},
    {"JournalFailed", [](GateInput& in) { in.journal_ok = false; }, GateDecision::kHold,
     GateReason::kJournalFailed},
    {"ImageQuality",
     [](GateInput& in) {
       in.image_quality_ok = false;
       in.registration_ok = false;
     },
     GateDecision::kSkip, GateReason::kImageQuality},
    {"StaleFrame", [](GateInput& in) { in.frame_age_ms = 151; }, GateDecision::kSkip,
     GateReason::kStaleFrame},
    {"UnpairedFrames", [](GateInput& in) { in.pair_skew_ms = 25; }, GateDecision::kSkip,
     GateReason::kUnpairedFrames},
    {"LowSimilarityRatio", [](GateInput& in) { in.similarity[0] = 0.4; }, GateDecision::kSkip,
     GateReason::kLowSimilarity},
    {"ViewsDisagree",
     [](GateInput& in) {
       in.similarity[0] = 0.5;  // ratio 0.77
       in.similarity[1] = 0.8;  // ratio 1.03
     },
     GateDecision::kSkip, GateReason::kViewsDisagree},
    {"SecondFailureStillSkips",
     [](GateInput& in) {
       in.registration_ok = false;
       in.consecutive_failures = 1;
     },
     GateDecision::kSkip, GateReason::kNoResult},
    {"ThirdFailureHolds",
     [](GateInput& in) {
       in.registration_ok = false;
       in.consecutive_failures = 2;
     },
     GateDecision::kHold, GateReason::kNoResult},
    {"TenthFailureStops",
     [](GateInput& in) {
       in.frame_age_ms = 500;
       in.consecutive_failures = 9;
     },
     GateDecision::kStop, GateReason::kStaleFrame},
    {"SafetyViolationAfterManyFailuresStops",
     [](GateInput& in) {
       in.step(0) = 5;
       in.consecutive_failures = 12;
     },
     GateDecision::kStop, GateReason::kStepTooLarge},
    {"TooManyViews", [](GateInput& in) { in.views = 5; }, GateDecision::kHold, GateReason::kNonFinite},
};

class GateTable : public ::testing::TestWithParam<GateCase> {};

TEST_P(GateTable, DecidesAsTheRulesSay) {
  GateInput in = good_input();
  GetParam().change(in);
  const GateOutput out = evaluate_gate(SafetyLimits{}, in);
  EXPECT_EQ(out.decision, GetParam().decision) << to_string(out.decision);
  EXPECT_EQ(out.reason, GetParam().reason) << to_string(out.reason);
  if (out.decision == GateDecision::kApply)
    EXPECT_EQ(out.consecutive_failures, 0);
  else
    EXPECT_EQ(out.consecutive_failures, in.consecutive_failures + 1);
}

INSTANTIATE_TEST_SUITE_P(Rules, GateTable, ::testing::ValuesIn(kCases),
                         [](const ::testing::TestParamInfo<GateCase>& p) {
                           return std::string(p.param.name);
                         });

TEST(Gate, ApplyResetsTheFailureCount) {
  GateInput in = good_input();
  in.consecutive_failures = 2;
  EXPECT_EQ(evaluate_gate(SafetyLimits{}, in).consecutive_failures, 0);
}

TEST(Gate, EveryDecisionAndReasonHasAName) {
  for (int d = 0; d <= 3; ++d) EXPECT_STRNE(to_string(static_cast<GateDecision>(d)), "?");
  constexpr int kLastReason = static_cast<int>(GateReason::kModelNotReady);
  for (int r = 0; r <= kLastReason; ++r) EXPECT_STRNE(to_string(static_cast<GateReason>(r)), "?");
  EXPECT_STREQ(to_string(static_cast<GateReason>(kLastReason + 1)), "?") << "a new reason: extend this test";
  for (int w = 0; w <= 5; ++w) EXPECT_STRNE(to_string(static_cast<BeamWithheld>(w)), "?");
}

// An APPLY sends its correction; the beam waits while the patient is still being moved into
// place: the cycle of an approved step beyond the step limit (the move after a resume), and
// every cycle whose read-back found the actuator more than one step limit from its target.
struct BeamCase {
  const char* name;
  std::function<void(GateInput&)> change;
  GateDecision decision;
  BeamWithheld withheld;
};

// The step of the cases below is zero unless they set one. The beam waits while the registered
// patient (offset_from_plan) or the actuator's travel still to make (travel_left) is beyond
// beam_tolerance_mm (2 mm, straight-line) or beam_tolerance_deg (2 degrees).
GateInput at_rest() {
  GateInput in = good_input();
  in.step.setZero();
  return in;
}

const std::vector<BeamCase> kBeamCases = {
    {"AllGood", [](GateInput&) {}, GateDecision::kApply, BeamWithheld::kNo},
    {"ApprovedStepWithinTheLimit",
     [](GateInput& in) {
       in.step(1) = 1.5;
       in.step_approved = true;
     },
     GateDecision::kApply, BeamWithheld::kNo},
    {"ApprovedStepBeyondTheLimit",
     [](GateInput& in) {
       in.step(1) = 8.0;
       in.step_approved = true;
     },
     GateDecision::kApply, BeamWithheld::kApprovedStep},
    {"ApprovedRotationBeyondTheLimit",
     [](GateInput& in) {
       in.step(5) = tracking::deg_to_rad(-3.0);
       in.step_approved = true;
     },
     GateDecision::kApply, BeamWithheld::kApprovedStep},
    {"OffsetAtTheTolerance", [](GateInput& in) { in.offset_from_plan(0) = -2.0; }, GateDecision::kApply,
     BeamWithheld::kNo},
    {"OffsetBeyondTheTolerance", [](GateInput& in) { in.offset_from_plan(2) = 2.01; }, GateDecision::kApply,
     BeamWithheld::kOutOfPlace},
    // An outside probe's case: a set-up error of 1.9 mm on each axis, each within the step limit,
    // is 3.3 mm out of place.
    {"DiagonalOffsetWithinTheStepLimitOnEachAxis",
     [](GateInput& in) { in.offset_from_plan << 1.9, -1.9, 1.9, 0, 0, 0; }, GateDecision::kApply,
     BeamWithheld::kOutOfPlace},
    {"RotatedBeyondTheTolerance", [](GateInput& in) { in.offset_from_plan(3) = tracking::deg_to_rad(2.1); },
     GateDecision::kApply, BeamWithheld::kOutOfPlace},
    {"RotationsTogetherBeyondTheTolerance",
     [](GateInput& in) {
       in.offset_from_plan(3) = tracking::deg_to_rad(1.5);
       in.offset_from_plan(4) = tracking::deg_to_rad(1.5);  // 2.12 degrees together
     },
     GateDecision::kApply, BeamWithheld::kOutOfPlace},
    {"TravelLeftAtTheTolerance", [](GateInput& in) { in.travel_left(1) = 2.0; }, GateDecision::kApply,
     BeamWithheld::kNo},
    {"TravelLeftBeyondTheTolerance",
     [](GateInput& in) {
       in.travel_left(0) = 1.5;
       in.travel_left(1) = 1.5;  // 2.12 mm
     },
     GateDecision::kApply, BeamWithheld::kActuatorTravelling},
    {"RotationLeftBeyondTheTolerance", [](GateInput& in) { in.travel_left(5) = tracking::deg_to_rad(2.1); },
     GateDecision::kApply, BeamWithheld::kActuatorTravelling},
    // Tracking: the couch follows the patient a step behind; this cycle's step is not judged.
    {"TrackingStepsDoNotCount",
     [](GateInput& in) {
       in.step(0) = 1.9;
       in.travel_left(0) = 1.5;
     },
     GateDecision::kApply, BeamWithheld::kNo},
    {"ApprovedStepAndTravelling",
     [](GateInput& in) {
       in.step(0) = -6.0;
       in.step_approved = true;
       in.travel_left(0) = 5.0;
     },
     GateDecision::kApply, BeamWithheld::kApprovedStep},
    {"OutOfPlaceBeforeTravelling",
     [](GateInput& in) {
       in.offset_from_plan(0) = 3.0;
       in.travel_left(0) = -3.0;
     },
     GateDecision::kApply, BeamWithheld::kOutOfPlace},
    {"NanTravelHolds", [](GateInput& in) { in.travel_left(1) = kNan; }, GateDecision::kHold, BeamWithheld::kNo},
    {"InfiniteTravelHolds", [](GateInput& in) { in.travel_left(4) = -kInf; }, GateDecision::kHold,
     BeamWithheld::kNo},
    {"NanOffsetHolds", [](GateInput& in) { in.offset_from_plan(5) = kNan; }, GateDecision::kHold,
     BeamWithheld::kNo},
    {"NothingWithheldWithoutAnApply",
     [](GateInput& in) {
       in.offset_from_plan(0) = 5.0;
       in.registration_ok = false;
     },
     GateDecision::kSkip, BeamWithheld::kNo},
    // The beam kept off for max_beam_withheld_s (10 s): a couch that never arrives, a patient out
    // of reach, is a HOLD (the operator is told), not a correction sent again and again.
    {"WithheldJustShortOfTheLimit",
     [](GateInput& in) {
       in.travel_left(0) = 3.0;
       in.beam_off_s = 9.99;
     },
     GateDecision::kApply, BeamWithheld::kActuatorTravelling},
    {"WithheldAtTheLimitHolds",
     [](GateInput& in) {
       in.travel_left(0) = 3.0;
       in.beam_off_s = 10.0;
     },
     GateDecision::kHold, BeamWithheld::kNo},
    {"OutOfPlaceAtTheLimitHolds",
     [](GateInput& in) {
       in.offset_from_plan(0) = 3.0;
       in.beam_off_s = 1e12;
     },
     GateDecision::kHold, BeamWithheld::kNo},
    {"ApprovedStepAtTheLimitHolds",
     [](GateInput& in) {
       in.step(1) = 8.0;
       in.step_approved = true;
       in.beam_off_s = 10.0;
     },
     GateDecision::kHold, BeamWithheld::kNo},
    {"InPlaceAfterALongWaitTreats", [](GateInput& in) { in.beam_off_s = 1e12; }, GateDecision::kApply,
     BeamWithheld::kNo},
    {"SkippedAfterALongWaitStaysASkip",
     [](GateInput& in) {
       in.registration_ok = false;
       in.beam_off_s = 60;
     },
     GateDecision::kSkip, BeamWithheld::kNo},
    {"NanBeamOffTimeHolds", [](GateInput& in) { in.beam_off_s = kNan; }, GateDecision::kHold, BeamWithheld::kNo},
    {"InfiniteBeamOffTimeHolds", [](GateInput& in) { in.beam_off_s = kInf; }, GateDecision::kHold,
     BeamWithheld::kNo},
};

class GateBeam : public ::testing::TestWithParam<BeamCase> {};

TEST_P(GateBeam, WithholdsTheBeamUntilThePatientIsInPlace) {
  GateInput in = at_rest();
  GetParam().change(in);
  const GateOutput out = evaluate_gate(SafetyLimits{}, in);
  EXPECT_EQ(out.decision, GetParam().decision) << to_string(out.decision);
  EXPECT_EQ(out.beam_withheld, GetParam().withheld) << to_string(out.beam_withheld);
  EXPECT_EQ(out.beam_allowed(), out.decision == GateDecision::kApply && GetParam().withheld == BeamWithheld::kNo);
  if (in.beam_off_s >= 10 && std::isfinite(in.beam_off_s) && out.decision == GateDecision::kHold) {
    EXPECT_EQ(out.reason, GateReason::kNotInPlace) << to_string(out.reason);
  }
}

// The limit is the scene's: a shorter one holds sooner, and the reason names the patient.
TEST(Gate, TheBeamOffTimeIsTheScenes) {
  SafetyLimits limits;
  limits.max_beam_withheld_s = 2.5;
  GateInput in = at_rest();
  in.offset_from_plan(2) = 4.0;
  in.beam_off_s = 2.4;
  EXPECT_EQ(evaluate_gate(limits, in).decision, GateDecision::kApply);
  in.beam_off_s = 2.5;
  const GateOutput out = evaluate_gate(limits, in);
  EXPECT_EQ(out.decision, GateDecision::kHold);
  EXPECT_EQ(out.reason, GateReason::kNotInPlace);
  EXPECT_FALSE(out.beam_allowed());
  EXPECT_EQ(out.consecutive_failures, 0) << "not a registration failure: it does not count towards FAULT";
  EXPECT_STREQ(to_string(GateReason::kNotInPlace), "patient not in place: the beam withheld too long");
}

INSTANTIATE_TEST_SUITE_P(Rules, GateBeam, ::testing::ValuesIn(kBeamCases),
                         [](const ::testing::TestParamInfo<BeamCase>& p) { return std::string(p.param.name); });

// The beam's tolerance is its own: a larger step limit does not let the beam on with the patient
// further from place (an outside probe's case: max_step_mm 10, a 7.7 mm move after a resume, the
// beam on at 7.7 mm).
TEST(Gate, TheBeamToleranceIsNotTheStepLimit) {
  SafetyLimits limits;
  limits.max_step_mm = 10;
  limits.max_total_mm = 20;
  GateInput in = at_rest();
  in.step(1) = -7.7;
  in.offset_from_plan(1) = 7.7;  // the frame shows the shift the move cancels
  in.step_approved = true;
  GateOutput out = evaluate_gate(limits, in);
  EXPECT_EQ(out.decision, GateDecision::kApply);
  EXPECT_EQ(out.beam_withheld, BeamWithheld::kOutOfPlace);
  in = at_rest();
  in.travel_left(1) = -7.0;  // the move under way, the next frame taken as it starts
  in.offset_from_plan(1) = 1.0;
  EXPECT_EQ(evaluate_gate(limits, in).beam_withheld, BeamWithheld::kActuatorTravelling);
  limits.beam_tolerance_mm = 0.5;
  limits.beam_tolerance_deg = 0.25;
  in = at_rest();
  in.offset_from_plan(1) = 0.6;
  EXPECT_EQ(evaluate_gate(limits, in).beam_withheld, BeamWithheld::kOutOfPlace);
  in.offset_from_plan(1) = 0.4;
  EXPECT_TRUE(evaluate_gate(limits, in).beam_allowed());
  in.travel_left(5) = tracking::deg_to_rad(0.3);
  EXPECT_EQ(evaluate_gate(limits, in).beam_withheld, BeamWithheld::kActuatorTravelling);
}

}  // namespace
}  // namespace lftrack::loop
