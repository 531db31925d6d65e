#include "lftrack/studies/verdict_commissioning.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include "lftrack/session/registration_judge.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/session/scene_verdict.hpp"
#include "lftrack/sim_devices/sim_detectors.hpp"
#include "quantile.hpp"

namespace lftrack::studies {

using session::make_scene_renderer;
using session::PreparedScene;
using session::RegistrationJudge;
using session::scene_detector_corrections;
using session::scene_tre;
using session::verdict_limits;
using sim_devices::make_scene_sim_detectors;
using sim_devices::SceneSimDetectors;

using loop::judge_registration;
using loop::judges_view_shift;
using loop::VerdictInput;
using loop::VerdictLimits;
namespace {

using tracking::Image;
using tracking::Pose;
using tracking::Vector6d;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

struct PlannedCase {
  CommissionCase kind;
  Vector6d gold = Vector6d::Zero();   // delta from nominal: mm, rad (the other patient's, for kOtherPatient)
  Vector6d start = Vector6d::Zero();  // delta from nominal
};

// How many of `total` bad cases each bad kind gets (weights; kinds that do not apply get none).
std::array<int, kCommissionCaseKinds> bad_counts(int total, bool swappable, bool other_patient) {
  std::array<int, kCommissionCaseKinds> weight{};
  weight[int(CommissionCase::kSwappedViews)] = swappable ? 2 : 0;
  weight[int(CommissionCase::kMirrored)] = 2;
  weight[int(CommissionCase::kBeyondEnvelope)] = 2;
  weight[int(CommissionCase::kWrongLevel)] = 2;
  weight[int(CommissionCase::kOtherPatient)] = other_patient ? 2 : 0;
  weight[int(CommissionCase::kNoise)] = 1;
  weight[int(CommissionCase::kBlank)] = 1;
  int sum = 0;
  for (int w : weight) sum += w;
  std::array<int, kCommissionCaseKinds> count{};
  int given = 0;
  for (int k = 0; k < kCommissionCaseKinds; ++k) given += count[k] = total * weight[k] / sum;
  for (int k = 0; given < total; k = (k + 1) % kCommissionCaseKinds)
    if (weight[k] > 0) ++count[k], ++given;
  return count;
}

std::vector<PlannedCase> plan_cases(const PreparedScene& p, const CommissionOptions& o, bool swappable) {
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> unit(-1, 1);
  const double t_mm = p.scene.envelope.translation_mm, r_rad = tracking::deg_to_rad(p.scene.envelope.rotation_deg);
  const auto within = [&](double fraction) {  // uniform in the envelope's box scaled by `fraction`
    Vector6d d;
    for (int i = 0; i < 3; ++i) d[i] = fraction * t_mm * unit(rng);
    for (int i = 3; i < 6; ++i) d[i] = fraction * r_rad * unit(rng);
    return d;
  };
  std::vector<PlannedCase> cases;
  const int align = o.good_cases / 2;
  for (int i = 0; i < o.good_cases; ++i) {
    PlannedCase c{i < align ? CommissionCase::kAlign : CommissionCase::kTrack};
    c.gold = within(0.9);  // the results of golds at the edge may just leave the envelope
    if (c.kind == CommissionCase::kTrack) {
      Vector6d near;
      for (int k = 0; k < 3; ++k) near[k] = 1.0 * unit(rng);
      for (int k = 3; k < 6; ++k) near[k] = tracking::deg_to_rad(0.5) * unit(rng);
      c.start = c.gold + near;
    }
    cases.push_back(c);
  }
  const auto counts = bad_counts(o.bad_cases, swappable, o.other_patient != nullptr);
  for (int k = 0; k < kCommissionCaseKinds; ++k)
    for (int i = 0; i < counts[std::size_t(k)]; ++i) {
      PlannedCase c{CommissionCase(k)};
      switch (c.kind) {
        case CommissionCase::kSwappedViews:
        case CommissionCase::kMirrored:
        case CommissionCase::kOtherPatient:
          c.gold = within(0.5);
          break;
        case CommissionCase::kBeyondEnvelope: {
          Eigen::Vector3d direction(unit(rng), unit(rng), unit(rng));
          if (direction.norm() < 1e-3) direction = Eigen::Vector3d::UnitZ();
          const double scale = 1.2 + 1.3 * (0.5 * (unit(rng) + 1));
          c.gold = within(0.5);
          c.gold.head<3>() = direction / direction.cwiseAbs().maxCoeff() * scale * t_mm;  // one axis at scale
          break;
        }
        case CommissionCase::kWrongLevel:
          c.gold = within(0.2);
          c.gold[2] += (i % 2 == 0 ? 1 : -1) * o.level_mm;
          break;
        default:
          break;
      }
      cases.push_back(c);
    }
  return cases;
}

Pose pose_of(const PreparedScene& p, const Vector6d& delta) {
  return tracking::apply_delta(p.nominal_T_room_from_ct, tracking::PoseDelta::from_vector(delta),
                               p.registration_origin_room_mm());
}

void mirror_left_right(std::vector<Image<std::uint16_t>>* frames) {
  for (Image<std::uint16_t>& f : *frames)
    for (int r = 0; r < f.rows(); ++r)
      for (int c = 0; c < f.cols() / 2; ++c) std::swap(f.at(r, c), f.at(r, f.cols() - 1 - c));
}

bool same_sizes(const PreparedScene& a, const PreparedScene& b) {
  if (a.scene.detectors.size() != b.scene.detectors.size()) return false;
  for (std::size_t v = 0; v < a.scene.detectors.size(); ++v)
    if (a.scene.detectors[v].view.rows != b.scene.detectors[v].view.rows ||
        a.scene.detectors[v].view.cols != b.scene.detectors[v].view.cols)
      return false;
  return true;
}

}  // namespace

const char* to_string(CommissionCase kind) {
  switch (kind) {
    case CommissionCase::kAlign:
      return "align";
    case CommissionCase::kTrack:
      return "track";
    case CommissionCase::kSwappedViews:
      return "swapped views";
    case CommissionCase::kMirrored:
      return "mirrored";
    case CommissionCase::kBeyondEnvelope:
      return "beyond the envelope";
    case CommissionCase::kWrongLevel:
      return "wrong level";
    case CommissionCase::kOtherPatient:
      return "another patient";
    case CommissionCase::kNoise:
      return "noise";
    case CommissionCase::kBlank:
      return "blank";
  }
  return "unknown";
}

bool must_refuse(CommissionCase kind) {
  return kind != CommissionCase::kAlign && kind != CommissionCase::kTrack;
}

Result<std::vector<CommissionCaseResult>> run_commission_cases(const PreparedScene& p, const CommissionOptions& o) {
  if (o.good_cases < 0 || o.bad_cases < 0 || o.good_cases + o.bad_cases == 0)
    return invalid_argument("commission: no cases to run");
  if (!(o.level_mm > 0)) return invalid_argument("commission: the vertebral level must be a positive distance");
  if (o.other_patient && !same_sizes(p, *o.other_patient))
    return invalid_argument("commission: the other patient's scene has detectors of other sizes than " +
                            p.scene.source + "'s; its frames cannot stand for this room's");
  const bool swappable = p.scene.detectors.size() >= 2 && p.scene.detectors[0].view.rows == p.scene.detectors[1].view.rows &&
                         p.scene.detectors[0].view.cols == p.scene.detectors[1].view.cols;
  const std::vector<PlannedCase> planned = plan_cases(p, o, swappable);

  auto limits = verdict_limits(p.scene, p.scene.registration.similarity);
  if (!limits.ok()) return limits.status();
  auto align_plan = tracking::registration_plan(p.scene.loop.align_plan);
  if (!align_plan.ok()) return align_plan.status().with_context("loop.align_plan");
  auto track_plan = tracking::registration_plan(p.scene.loop.track_plan);
  if (!track_plan.ok()) return track_plan.status().with_context("loop.track_plan");
  auto simulated = make_scene_sim_detectors(p, o.pool);
  if (!simulated.ok()) return simulated.status();
  std::optional<SceneSimDetectors> other;
  if (o.other_patient) {
    auto made = make_scene_sim_detectors(*o.other_patient, o.pool);
    if (!made.ok()) return made.status().with_context("the other patient");
    other.emplace(std::move(made).value());
  }
  auto corrections = scene_detector_corrections(p, true);
  if (!corrections.ok()) return corrections.status();
  if (simulated->correction)
    for (std::size_t v = 0; v < corrections->size(); ++v)
      if (p.scene.detectors[v].calibration_file.empty()) (*corrections)[v] = *simulated->correction;
  auto renderer = make_scene_renderer(p, o.renderer, o.light_field_dir, o.pool);
  if (!renderer.ok()) return renderer.status();
  auto judge = RegistrationJudge::create(p, *renderer, p.scene.registration, *corrections, *limits, o.pool,
                                         RegistrationJudge::ViewCheck::kAlways);
  if (!judge.ok()) return judge.status();

  std::vector<Image<std::uint16_t>> raw = simulated->detectors.make_frames();
  std::vector<CommissionCaseResult> results;
  results.reserve(planned.size());
  for (std::size_t i = 0; i < planned.size(); ++i) {
    const PlannedCase& c = planned[i];
    const std::uint64_t seed = o.seed * 1000003 + i * 7919;
    bool has_gold = true;
    switch (c.kind) {
      case CommissionCase::kNoise: {
        std::mt19937_64 rng(seed);
        for (std::size_t v = 0; v < raw.size(); ++v) {
          std::uniform_int_distribution<int> counts(0, (1 << p.scene.detectors[v].bits) - 1);
          for (auto& px : raw[v].pixels()) px = static_cast<std::uint16_t>(counts(rng));
        }
        has_gold = false;
        break;
      }
      case CommissionCase::kBlank:
        for (std::size_t v = 0; v < raw.size(); ++v)
          std::fill(raw[v].pixels().begin(), raw[v].pixels().end(),
                    static_cast<std::uint16_t>((1 << p.scene.detectors[v].bits) / 2));
        has_gold = false;
        break;
      case CommissionCase::kOtherPatient:
        other->detectors.forget_previous_frames();  // no lag of the case before
        LFTRACK_RETURN_IF_ERROR(other->detectors.expose(pose_of(*o.other_patient, c.gold), seed, &raw));
        has_gold = false;
        break;
      default:
        simulated->detectors.forget_previous_frames();
        LFTRACK_RETURN_IF_ERROR(simulated->detectors.expose(pose_of(p, c.gold), seed, &raw));
        if (c.kind == CommissionCase::kSwappedViews) std::swap(raw[0], raw[1]);
        if (c.kind == CommissionCase::kMirrored) mirror_left_right(&raw);
        break;
    }
    const bool tracking = c.kind == CommissionCase::kTrack;
    auto judged = (*judge)->judge(raw, pose_of(p, c.start), tracking ? *track_plan : *align_plan);
    if (c.kind == CommissionCase::kSwappedViews) std::swap(raw[0], raw[1]);  // the frames keep their views' sizes
    if (!judged.ok()) return judged.status().with_context(std::string("commission case ") + to_string(c.kind));
    CommissionCaseResult r;
    r.kind = c.kind;
    r.gold_delta = c.gold;
    r.registered = judged->registered;
    r.input = judged->input;
    r.ms = judged->registered ? judged->result.elapsed_ms : 0;
    r.view_check_ms = judged->view_check_ms;
    r.tre_mean_mm = judged->registered && has_gold ? scene_tre(p, judged->result.T_room_from_ct, pose_of(p, c.gold)).mean_mm
                                                   : kNaN;
    results.push_back(r);
    if (o.progress) o.progress(int(i + 1), int(planned.size()));
  }
  return results;
}

double lowest_view_similarity(const VerdictInput& in) {
  if (in.views < 1) return kNaN;
  double low = in.similarity[0];
  for (int v = 1; v < in.views; ++v) low = std::min(low, in.similarity[std::size_t(v)]);
  return low;
}

double lowest_view_check_ncc(const VerdictInput& in) {
  if (in.views < 1 || !in.has_check_ncc) return kNaN;
  double low = in.check_ncc[0];
  for (int v = 1; v < in.views; ++v) low = std::min(low, in.check_ncc[std::size_t(v)]);
  return low;
}

double largest_view_shift_mm(const VerdictInput& in) {
  if (in.views < 1 || !in.has_view_shift) return kNaN;
  double most = in.view_shift_mm[0];
  for (int v = 1; v < in.views; ++v) most = std::max(most, in.view_shift_mm[std::size_t(v)]);
  return most;
}

double choose_view_shift_limit(const std::vector<CommissionCaseResult>& cases, const VerdictLimits& defaults,
                               double tolerance_mm) {
  if (!judges_view_shift(defaults)) return defaults.max_view_shift_mm;
  double largest = -1;
  for (const CommissionCaseResult& c : cases)
    if (is_right_result(c, tolerance_mm) && c.input.has_view_shift)
      largest = std::max(largest, largest_view_shift_mm(c.input));
  if (!(largest >= 0)) return defaults.max_view_shift_mm;
  return std::min(defaults.max_view_shift_mm, std::max(kMinViewShiftLimitMm, 2 * largest));
}

OtherChecks other_checks(const std::vector<CommissionCaseResult>& cases, const VerdictLimits& defaults,
                         double tolerance_mm) {
  OtherChecks o;
  o.view_check = judges_view_shift(defaults);
  VerdictLimits edge_only = defaults, neither = defaults;
  edge_only.max_view_shift_mm = neither.max_view_shift_mm = std::numeric_limits<double>::infinity();
  neither.envelope_edge_mm = neither.envelope_edge_deg = 0;
  std::vector<double> shifts, ms;
  for (const CommissionCaseResult& c : cases) {
    const bool right = is_right_result(c, tolerance_mm);
    const bool ok_neither = judge_registration(neither, c.input).ok;
    const bool ok_edge = judge_registration(edge_only, c.input).ok;
    const bool ok_both = judge_registration(defaults, c.input).ok;
    if (!right) {
      o.accepted_wrong_without += ok_neither;
      o.accepted_wrong_edge += ok_edge;
      o.accepted_wrong_both += ok_both;
    } else {
      o.rejected_right_edge += ok_neither && !ok_edge;
      o.rejected_right_view += ok_edge && !ok_both;
      if (c.input.has_view_shift) shifts.push_back(largest_view_shift_mm(c.input));
    }
    if (c.input.has_view_shift) ms.push_back(c.view_check_ms);
  }
  const auto at = [](const std::vector<double>& v, double q) { return v.empty() ? kNaN : quantile(v, q); };
  o.right_with_shift = static_cast<int>(shifts.size());
  o.right_shift_median_mm = at(shifts, 0.5);
  o.right_shift_max_mm = at(shifts, 1.0);
  o.check_ms_median = at(ms, 0.5);
  o.check_ms_p95 = at(ms, 0.95);
  return o;
}

bool is_right_result(const CommissionCaseResult& c, double tolerance_mm) {
  return !must_refuse(c.kind) && c.registered && c.tre_mean_mm < tolerance_mm;
}

VerdictLimits without_floors(VerdictLimits limits) {
  limits.min_similarity = limits.min_check_ncc = -std::numeric_limits<double>::infinity();
  limits.max_view_shift_mm = std::numeric_limits<double>::infinity();
  return limits;
}

std::array<CommissionTally, kCommissionCaseKinds + 1> tally_commission(const std::vector<CommissionCaseResult>& cases,
                                                                       const VerdictLimits& limits,
                                                                       double tolerance_mm) {
  std::array<CommissionTally, kCommissionCaseKinds + 1> t{};
  for (const CommissionCaseResult& c : cases) {
    const bool accepted = judge_registration(limits, c.input).ok;
    const bool right = is_right_result(c, tolerance_mm);
    for (CommissionTally* k : {&t[std::size_t(c.kind)], &t[kCommissionCaseKinds]}) {
      ++k->cases;
      (accepted ? (right ? k->accepted_right : k->accepted_wrong) : (right ? k->rejected_right : k->rejected_wrong))++;
    }
  }
  return t;
}

FloorMargins floor_margins(const VerdictLimits& defaults, double min_margin_fraction) {
  return {min_margin_fraction * (defaults.min_similarity - defaults.no_information_similarity),
          min_margin_fraction * defaults.min_check_ncc};
}

ChosenFloors choose_floors(const std::vector<CommissionCaseResult>& cases, const VerdictLimits& defaults,
                           double tolerance_mm, double min_margin_fraction) {
  const VerdictLimits open = without_floors(defaults);
  const FloorMargins m = floor_margins(defaults, min_margin_fraction);
  struct Point {
    double s, c;
  };
  std::vector<Point> wrong, right;
  for (const CommissionCaseResult& k : cases) {
    if (!judge_registration(open, k.input).ok) continue;
    const Point pt{lowest_view_similarity(k.input), lowest_view_check_ncc(k.input)};
    if (!std::isfinite(pt.s) || !std::isfinite(pt.c)) continue;
    (is_right_result(k, tolerance_mm) ? right : wrong).push_back(pt);
  }
  const double s_lowest = defaults.no_information_similarity +
                          0.5 * (defaults.min_similarity - defaults.no_information_similarity);
  const double c_lowest = 0.5 * defaults.min_check_ncc;
  // Candidate similarity floors: the lowest allowed, and halfway between neighbouring values.
  std::vector<double> values;
  for (const auto* set : {&wrong, &right})
    for (const Point& pt : *set) values.push_back(pt.s);
  std::sort(values.begin(), values.end());
  std::vector<double> candidates{s_lowest};
  for (std::size_t i = 1; i < values.size(); ++i)
    if (values[i] > values[i - 1] && 0.5 * (values[i] + values[i - 1]) > s_lowest)
      candidates.push_back(0.5 * (values[i] + values[i - 1]));
  double best_s = s_lowest, best_c = c_lowest, best_margin = -1;
  int best_kept = -1;
  for (double s_floor : candidates) {
    // The highest wrong check NCC that the similarity floor does not refuse by its margin.
    double c_needed = -std::numeric_limits<double>::infinity();
    for (const Point& w : wrong)
      if (w.s > s_floor - m.similarity) c_needed = std::max(c_needed, w.c);
    double c_right_above = std::numeric_limits<double>::infinity();
    for (const Point& r : right)
      if (r.s >= s_floor && r.c >= c_needed + m.check_ncc) c_right_above = std::min(c_right_above, r.c);
    double c_floor = c_lowest;
    if (std::isfinite(c_needed))
      c_floor = std::max(0.5 * (c_needed + (std::isfinite(c_right_above) ? c_right_above : 1.0)),
                         c_needed + m.check_ncc);
    c_floor = std::max(c_floor, c_lowest);
    int kept = 0;
    for (const Point& r : right) kept += r.s >= s_floor && r.c >= c_floor;
    const double margin = std::isfinite(c_needed) ? c_floor - c_needed : 1.0;
    if (kept > best_kept || (kept == best_kept && margin > best_margin)) {
      best_kept = kept;
      best_margin = margin;
      best_s = s_floor;
      best_c = c_floor;
    }
  }
  // Each floor then rises to the middle of the gap between the right results kept and the wrong
  // ones just below them, where that is higher: both checks refuse what either can (two guards
  // where one would do), and neither sits against the values it separates.
  double s_right_min = std::numeric_limits<double>::infinity(), c_right_min = s_right_min;
  for (const Point& r : right)
    if (r.s >= best_s && r.c >= best_c) s_right_min = std::min(s_right_min, r.s), c_right_min = std::min(c_right_min, r.c);
  if (std::isfinite(s_right_min)) {
    double s_from = s_lowest, c_from = c_lowest;
    for (const Point& w : wrong) {
      if (w.s < s_right_min) s_from = std::max(s_from, w.s);
      if (w.c < c_right_min) c_from = std::max(c_from, w.c);
    }
    best_s = std::max(best_s, 0.5 * (s_from + s_right_min));
    best_c = std::max(best_c, 0.5 * (c_from + c_right_min));
  }
  ChosenFloors chosen;
  chosen.min_similarity = best_s;
  chosen.min_check_ncc = best_c;
  chosen.wrong_similarity_below = chosen.right_similarity_above = kNaN;
  chosen.wrong_check_below = chosen.right_check_above = kNaN;
  for (const Point& w : wrong) {  // the wrong results nearest below each floor
    if (w.s < best_s && !(w.s <= chosen.wrong_similarity_below)) chosen.wrong_similarity_below = w.s;
    if (w.c < best_c && !(w.c <= chosen.wrong_check_below)) chosen.wrong_check_below = w.c;
  }
  if (std::isfinite(s_right_min)) chosen.right_similarity_above = s_right_min, chosen.right_check_above = c_right_min;
  return chosen;
}

}  // namespace lftrack::studies
