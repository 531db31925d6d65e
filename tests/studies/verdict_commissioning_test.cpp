// The commissioning's arithmetic on cases made up here (verdict_commissioning.hpp): the tally's
// four outcomes per kind, and floors that refuse every wrong result and keep the right ones,
// each halfway between what it separates, never below its lower bound.

#include <gtest/gtest.h>

#include <cmath>
#include <utility>
#include <vector>

#include "lftrack/studies/verdict_commissioning.hpp"

namespace lftrack::session {

using studies::choose_floors;
using studies::ChosenFloors;
using studies::CommissionCase;
using studies::CommissionCaseResult;
using studies::CommissionTally;
using studies::floor_margins;
using studies::FloorMargins;
using studies::kCommissionCaseKinds;
using studies::kDefaultFloorMarginFraction;
using studies::largest_view_shift_mm;
using studies::must_refuse;

using loop::judge_registration;
using loop::VerdictLimits;
namespace {

// A registered two-view case whose lowest view scores `s` (the measure) and `c` (check NCC).
CommissionCaseResult judged(CommissionCase kind, double s, double c, double tre_mm = 0.3) {
  CommissionCaseResult r;
  r.kind = kind;
  r.registered = true;
  r.tre_mean_mm = tre_mm;
  r.input.views = 2;
  r.input.pose_finite = true;
  r.input.similarity = {s, s + 0.01};
  r.input.has_check_ncc = true;
  r.input.check_ncc = {c, c + 0.01};
  return r;
}

VerdictLimits ncc_defaults() {
  VerdictLimits limits;
  limits.measure = "ncc";
  limits.min_similarity = 0.76;
  limits.no_information_similarity = 0;
  limits.min_check_ncc = 0.76;
  limits.min_view_ratio = 0.5;
  limits.envelope = {10, 5};
  return limits;
}

TEST(VerdictCommissioning, TallyCountsTheFourOutcomesPerKindAndInAll) {
  const VerdictLimits limits = ncc_defaults();
  std::vector<CommissionCaseResult> cases = {
      judged(CommissionCase::kAlign, 0.95, 0.95),        // accepted, right
      judged(CommissionCase::kAlign, 0.95, 0.95, 4.0),   // accepted, wrong (a false accept)
      judged(CommissionCase::kTrack, 0.70, 0.95),        // rejected, right (a false reject)
      judged(CommissionCase::kSwappedViews, 0.5, 0.5),   // rejected, wrong
      judged(CommissionCase::kWrongLevel, 0.9, 0.9),     // accepted, wrong: a bad kind is never right
  };
  CommissionCaseResult blank;  // the quality gate refused it: never registered
  blank.kind = CommissionCase::kBlank;
  blank.input.views = 2;
  blank.input.image_quality[0] = tracking::FrameQualityIssue::kUniform;
  blank.tre_mean_mm = std::nan("");
  cases.push_back(blank);
  const auto t = tally_commission(cases, limits, 2.0);
  const CommissionTally& align = t[int(CommissionCase::kAlign)];
  EXPECT_EQ(align.cases, 2);
  EXPECT_EQ(align.accepted_right, 1);
  EXPECT_EQ(align.accepted_wrong, 1);
  EXPECT_EQ(t[int(CommissionCase::kTrack)].rejected_right, 1);
  EXPECT_EQ(t[int(CommissionCase::kSwappedViews)].rejected_wrong, 1);
  EXPECT_EQ(t[int(CommissionCase::kWrongLevel)].accepted_wrong, 1);
  EXPECT_EQ(t[int(CommissionCase::kBlank)].rejected_wrong, 1);
  const CommissionTally& all = t[kCommissionCaseKinds];
  EXPECT_EQ(all.cases, 6);
  EXPECT_EQ(all.accepted_right, 1);
  EXPECT_EQ(all.accepted_wrong, 2);
  EXPECT_EQ(all.rejected_right, 1);
  EXPECT_EQ(all.rejected_wrong, 2);
}

// Right results score 0.90-0.99 on both checks; swapped views 0.40-0.60; one wrong level scores
// like a right result on the measure (0.95) and passes the default check floor (0.76) at 0.80: the check's floor must
// refuse it, and both floors sit in the middle of their gaps.
TEST(VerdictCommissioning, FloorsRefuseEveryWrongResultAndKeepTheRightOnes) {
  std::vector<CommissionCaseResult> cases;
  for (int i = 0; i < 20; ++i) cases.push_back(judged(CommissionCase::kAlign, 0.90 + 0.0045 * i, 0.90 + 0.0045 * i));
  for (int i = 0; i < 10; ++i) cases.push_back(judged(CommissionCase::kSwappedViews, 0.40 + 0.02 * i, 0.40 + 0.02 * i));
  cases.push_back(judged(CommissionCase::kWrongLevel, 0.95, 0.80));
  const VerdictLimits defaults = ncc_defaults();
  const ChosenFloors floors = choose_floors(cases, defaults, 2.0);
  VerdictLimits chosen = defaults;
  chosen.min_similarity = floors.min_similarity;
  chosen.min_check_ncc = floors.min_check_ncc;
  const CommissionTally all = tally_commission(cases, chosen, 2.0)[kCommissionCaseKinds];
  EXPECT_EQ(all.accepted_wrong, 0);
  EXPECT_EQ(all.accepted_right, 20);
  EXPECT_NEAR(floors.min_check_ncc, 0.5 * (0.80 + 0.90), 1e-9);  // the wrong level's 0.80 and the lowest right
  EXPECT_NEAR(floors.min_similarity, 0.5 * (0.58 + 0.90), 1e-9);  // the highest swapped 0.58 and the lowest right
  EXPECT_NEAR(floors.wrong_check_below, 0.80, 1e-9);
  EXPECT_NEAR(floors.right_check_above, 0.90, 1e-9);
  // The defaults (0.76 both) let the wrong level by: this is what commissioning is for.
  EXPECT_EQ(tally_commission(cases, defaults, 2.0)[kCommissionCaseKinds].accepted_wrong, 1);
}

// A wrong result that scores above most right ones on both checks: no floors keep every right
// result, and the chosen ones still accept nothing wrong, losing as few right ones as they can.
TEST(VerdictCommissioning, AWrongResultAmongTheRightOnesCostsRightOnesNotSafety) {
  std::vector<CommissionCaseResult> cases;
  for (int i = 0; i < 10; ++i) cases.push_back(judged(CommissionCase::kAlign, 0.90 + 0.01 * i, 0.90 + 0.01 * i));
  cases.push_back(judged(CommissionCase::kOtherPatient, 0.955, 0.955));
  for (const auto& [margin, kept] : {std::pair{0.0, 4}, std::pair{kDefaultFloorMarginFraction, 4}, std::pair{0.02, 2}}) {
    const ChosenFloors floors = choose_floors(cases, ncc_defaults(), 2.0, margin);
    VerdictLimits chosen = ncc_defaults();
    chosen.min_similarity = floors.min_similarity;
    chosen.min_check_ncc = floors.min_check_ncc;
    const CommissionTally all = tally_commission(cases, chosen, 2.0)[kCommissionCaseKinds];
    EXPECT_EQ(all.accepted_wrong, 0) << margin;
    // Without a margin, and with the default one (0.0038), 0.96 .. 0.99; with 0.02 a floor at
    // least 0.0152 above 0.955.
    EXPECT_EQ(all.accepted_right, kept) << margin;
  }
}

// The margin rule: a wrong result 0.005 below the lowest right one's check NCC. Without a margin
// the check floor splits that gap and keeps every right result; with one, the floor that refuses
// the wrong result sits at least the margin above it, and the right results inside the margin
// are the price (never a wrong result accepted).
TEST(VerdictCommissioning, EachWrongResultIsRefusedByAFloorWithItsMargin) {
  std::vector<CommissionCaseResult> cases;
  for (int i = 0; i < 10; ++i) cases.push_back(judged(CommissionCase::kAlign, 0.90 + 0.01 * i, 0.90 + 0.01 * i));
  cases.push_back(judged(CommissionCase::kWrongLevel, 0.95, 0.895));
  const VerdictLimits defaults = ncc_defaults();
  const ChosenFloors thin = choose_floors(cases, defaults, 2.0, 0.0);
  EXPECT_NEAR(thin.min_check_ncc, 0.8975, 1e-9);
  const ChosenFloors wide = choose_floors(cases, defaults, 2.0, 0.02);
  const FloorMargins m = floor_margins(defaults, 0.02);
  EXPECT_NEAR(m.check_ncc, 0.0152, 1e-12);
  EXPECT_NEAR(m.similarity, 0.0152, 1e-12);
  EXPECT_GE(wide.min_check_ncc - 0.895, m.check_ncc - 1e-12);
  VerdictLimits chosen = defaults;
  chosen.min_similarity = wide.min_similarity;
  chosen.min_check_ncc = wide.min_check_ncc;
  const CommissionTally all = tally_commission(cases, chosen, 2.0)[kCommissionCaseKinds];
  EXPECT_EQ(all.accepted_wrong, 0);
  EXPECT_EQ(all.accepted_right, 8);  // 0.92 .. 0.99: 0.90 and 0.91 lie within the margin
}

// The view check is a second line: the floors are chosen to refuse every wrong result without
// it, since tracking cycles run it only every Nth cycle.
TEST(VerdictCommissioning, TheFloorsDoNotLeanOnTheViewCheck) {
  std::vector<CommissionCaseResult> cases;
  for (int i = 0; i < 10; ++i) cases.push_back(judged(CommissionCase::kAlign, 0.90 + 0.01 * i, 0.90 + 0.01 * i));
  CommissionCaseResult pulled = judged(CommissionCase::kWrongLevel, 0.95, 0.85);
  pulled.input.has_view_shift = true;
  pulled.input.view_shift_mm = {3.0, 0.2};
  cases.push_back(pulled);
  VerdictLimits defaults = ncc_defaults();
  defaults.max_view_shift_mm = 1.0;
  EXPECT_FALSE(judge_registration(defaults, pulled.input).ok) << "the view check refuses it";
  const ChosenFloors floors = choose_floors(cases, defaults, 2.0, 0.0);
  EXPECT_GT(floors.min_check_ncc, 0.85) << "and the check floor refuses it too";
  EXPECT_NEAR(largest_view_shift_mm(pulled.input), 3.0, 1e-12);
}

// With nothing wrong to separate, a floor is not lowered past halfway between what unrelated
// images score and the measure's default.
TEST(VerdictCommissioning, FloorsDoNotFallBelowHalfwayToTheDefault) {
  std::vector<CommissionCaseResult> cases;
  for (int i = 0; i < 10; ++i) cases.push_back(judged(CommissionCase::kAlign, 0.10 + 0.01 * i, 0.10 + 0.01 * i));
  const ChosenFloors floors = choose_floors(cases, ncc_defaults(), 2.0);
  EXPECT_GE(floors.min_similarity, 0.38 - 1e-12);
  EXPECT_GE(floors.min_check_ncc, 0.38 - 1e-12);
}

TEST(VerdictCommissioning, OnlyTheGoodKindsMayBeAccepted) {
  EXPECT_FALSE(must_refuse(CommissionCase::kAlign));
  EXPECT_FALSE(must_refuse(CommissionCase::kTrack));
  for (int k = 2; k < kCommissionCaseKinds; ++k) EXPECT_TRUE(must_refuse(CommissionCase(k))) << to_string(CommissionCase(k));
}

}  // namespace
}  // namespace lftrack::session
