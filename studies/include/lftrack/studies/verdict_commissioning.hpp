#pragma once
// Commissioning the registration verdict for one scene (issue 52), as a physicist commissions a
// system: registrations of simulated frames the verdict must accept (the patient anywhere in the
// envelope, registered cold from the nominal pose as the alignment does, or warm from near the
// patient as tracking does) and of frames it must refuse (the views swapped, the frames mirrored,
// the patient beyond the envelope or one vertebral level off, another patient's anatomy, noise,
// flat frames); the floors that refuse every wrong result and keep as many right ones as can be;
// and, per kind, how often the verdict accepts wrong results (false accepts: what can hurt a
// patient) and rejects right ones (false rejects: lost treatment time), at the measure's default
// floors and at the commissioned ones.
//
// A result is right when its mean TRE over the scene's box is under the tolerance (the scene's
// safety.beam_tolerance_mm unless given) for a good case; every bad case must be refused.

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::studies {

enum class CommissionCase : std::uint8_t {
  kAlign,           // good: cold, from the nominal pose, the patient anywhere in the envelope
  kTrack,           // good: warm, from within 1 mm / 0.5 deg per axis of the patient (the track plan)
  kSwappedViews,    // bad: the frames of the first two views exchanged
  kMirrored,        // bad: every frame mirrored left to right
  kBeyondEnvelope,  // bad: the patient 1.2 to 2.5 envelopes away
  kWrongLevel,      // bad: the patient one vertebral level along the room's z, either way
  kOtherPatient,    // bad: frames of another patient (another scene's CT, its own room)
  kNoise,           // bad: uniform noise over the detector's range
  kBlank,           // bad: flat frames
};
inline constexpr int kCommissionCaseKinds = 9;
const char* to_string(CommissionCase kind);
bool must_refuse(CommissionCase kind);

struct CommissionOptions {
  int good_cases = 100;  // half alignments, half tracking
  int bad_cases = 1000;  // spread over the bad kinds that apply
  std::uint64_t seed = 1;
  double tolerance_mm = 0;  // 0: the scene's safety.beam_tolerance_mm
  double level_mm = 30;     // one vertebral level (lumbar about 35 mm, thoracic about 25 mm)
  const session::PreparedScene* other_patient = nullptr;  // null: no other-patient cases
  std::string renderer = "lightfield";
  std::string light_field_dir;  // empty: the scene's default folder
  tracking::ThreadPool* pool = nullptr;
  std::function<void(int done, int total)> progress;
};

struct CommissionCaseResult {
  CommissionCase kind = CommissionCase::kAlign;
  tracking::Vector6d gold_delta = tracking::Vector6d::Zero();  // the patient, from the nominal pose: mm, rad
  bool registered = false;  // false: the image-quality gate refused the frames
  loop::VerdictInput input;  // what the verdict judges (re-judged with any floors)
  double tre_mean_mm = 0;   // against the gold pose; NaN where there is none (no registration, another CT)
  double ms = 0;            // the registration's time
  double view_check_ms = 0;  // the view check's (each view registered alone), when the scene has one
};

// The cases, in a fixed order drawn from options.seed; the same options give the same cases.
Result<std::vector<CommissionCaseResult>> run_commission_cases(const session::PreparedScene& scene,
                                                               const CommissionOptions& options);

struct CommissionTally {
  int cases = 0;
  int accepted_right = 0, accepted_wrong = 0;  // accepted_wrong: the false accepts
  int rejected_right = 0, rejected_wrong = 0;  // rejected_right: the false rejects
};
// Per kind (index: the enum's value) and, last, all kinds together; each case judged with `limits`.
std::array<CommissionTally, kCommissionCaseKinds + 1> tally_commission(
    const std::vector<CommissionCaseResult>& cases, const loop::VerdictLimits& limits, double tolerance_mm);

// The floors chosen from `cases`: every wrong result the other checks accept is refused by one of
// them, and as many right ones as can be are kept; each floor sits halfway between the values it
// separates. Neither goes below halfway between what unrelated images score and the measure's
// default (the defaults in `defaults`).
struct ChosenFloors {
  double min_similarity = 0, min_check_ncc = 0;
  // The lowest view's values either side of each floor: the wrong result nearest below it (NaN:
  // none needed it) and the right result nearest above it (NaN: none kept).
  double wrong_similarity_below = 0, right_similarity_above = 0;
  double wrong_check_below = 0, right_check_above = 0;
};
//
// The margin rule: every wrong result is refused by at least one floor by that floor's margin
// (floor_margins: `min_margin_fraction` of the measure's default floor above its no-information
// value, and of the default check NCC floor), not merely by being below it: where right and wrong
// results nearly touch, a wrong result whose noise came out a little kinder would pass a floor
// that sits just above the highest one seen. The rule costs right results, never safety.
struct FloorMargins {
  double similarity = 0;  // the measure's units
  double check_ncc = 0;
};
FloorMargins floor_margins(const loop::VerdictLimits& defaults, double min_margin_fraction);
inline constexpr double kDefaultFloorMarginFraction = 0.005;
ChosenFloors choose_floors(const std::vector<CommissionCaseResult>& cases,
                           const loop::VerdictLimits& defaults, double tolerance_mm,
                           double min_margin_fraction = kDefaultFloorMarginFraction);

// The largest of the views' shifts when each is registered alone (view_agreement.hpp); NaN where
// the check did not run.
double largest_view_shift_mm(const loop::VerdictInput& input);

// The view check's limit for the scene (defaults.max_view_shift_mm where it has one): twice the
// largest shift of the right results (each view registered alone from a right result moves the
// target 0.1-0.3 mm), at least kMinViewShiftLimitMm, at most the scene's; the scene's when no
// right result was checked, infinity when the scene has no view check. Chosen from the right
// results alone: the floors refuse every wrong result without it (without_floors), so it can
// cost right results, never let a wrong one by.
inline constexpr double kMinViewShiftLimitMm = 0.25;
double choose_view_shift_limit(const std::vector<CommissionCaseResult>& cases,
                               const loop::VerdictLimits& defaults, double tolerance_mm);

// A right result: a good case registered to within the tolerance (mean TRE). Every other case is
// wrong, whatever it scores: a bad case must be refused.
bool is_right_result(const CommissionCaseResult& c, double tolerance_mm);

// `limits` with both floors open, and without the view check: what image quality, finiteness,
// agreement, the envelope and its edge let by, which is what the floors decide. The view check
// (each view registered alone) is not among them: tracking cycles run it only every Nth cycle,
// so the floors must refuse every wrong result without it; it is a second line behind them.
loop::VerdictLimits without_floors(loop::VerdictLimits limits);

// What the verdict's checks beyond the floors (the envelope's edge band, each view registered
// alone) do at the measure's default floors, the floors an uncommissioned scene judges with: the
// wrong results accepted without them, with the edge band, and with both; and what the view
// check measured of right results and what it cost.
struct OtherChecks {
  int accepted_wrong_without = 0, accepted_wrong_edge = 0, accepted_wrong_both = 0;
  int rejected_right_edge = 0, rejected_right_view = 0;  // right results each refused (alone)
  int right_with_shift = 0;
  static constexpr double kNone = std::numeric_limits<double>::quiet_NaN();  // the view check did not run
  double right_shift_median_mm = kNone, right_shift_max_mm = kNone;
  double check_ms_median = kNone, check_ms_p95 = kNone;
  bool view_check = false;
};

OtherChecks other_checks(const std::vector<CommissionCaseResult>& cases, const loop::VerdictLimits& defaults,
                         double tolerance_mm);

// The lowest view's similarity and check NCC of a judged case (the check: NaN where it did not
// run; a case the quality gate refused holds no similarity: look at `registered` first).
double lowest_view_similarity(const loop::VerdictInput& input);
double lowest_view_check_ncc(const loop::VerdictInput& input);

}  // namespace lftrack::studies
