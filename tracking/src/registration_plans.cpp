// The named registration plans (registration.hpp lists them and says what each is for).

#include <string>
#include <vector>

#include "lftrack/tracking/registration.hpp"

namespace lftrack::tracking {

// The robust plans' high-pass (sigma, mm on the detector): the best of 5, 7, 10 and 15 mm on the
// lumbar CT's clinical and ideal frames (BENCHMARKS.md, "X-rays that differ from the planning CT").
constexpr double kRobustHighPassMm = 7.0;

std::vector<std::string> registration_plan_names() {
  return {"papers",     "decoupled",       "quadratic", "cmaes",           "warm", "robust", "warm-robust",
          "robust-ncc", "warm-robust-ncc", "pyramid",   "warm-robust-fast"};
}

Result<RegistrationPlan> registration_plan(const std::string& name) {
  RegistrationPlan plan;
  plan.name = name;
  if (name == "papers" || name == "decoupled") {
    const std::string opt = name == "papers" ? "best-neighbour" : "decoupled";
    plan.passes = {{opt, 1.5, 1, 5.0, 0.5, 3000, ""}, {opt, 0.0, 1, 2.0, 0.1, 3000, ""}};
  } else if (name == "quadratic") {
    plan.passes = {{"quadratic-neighbour", 1.5, 4, 5.0, 0.5, 3000, ""},
                   {"quadratic-neighbour", 0.0, 1, 2.0, 0.1, 3000, ""}};
  } else if (name == "cmaes") {
    plan.passes = {{"cmaes", 1.5, 2, 2.5, 0.5, 3000, ""}, {"quadratic-neighbour", 0.0, 1, 1.0, 0.1, 3000, ""}};
  } else if (name == "warm") {
    plan.passes = {{"quadratic-neighbour", 0.0, 8, 1.0, 0.5, 400, ""},
                   {"quadratic-neighbour", 0.0, 4, 0.5, 0.25, 400, ""},
                   {"quadratic-neighbour", 0.0, 1, 0.25, 0.25, 200, ""}};
  } else if (name == "robust" || name == "robust-ncc") {
    const std::string measure = name == "robust" ? "rncc" : "ncc";
    plan.passes = {{"quadratic-neighbour", 1.5, 4, 5.0, 0.5, 3000, "", 0},
                   {"quadratic-neighbour", 0.0, 1, 2.0, 0.1, 3000, measure, kRobustHighPassMm}};
    if (name == "robust") {
      // The shift first, rotations held, on the coarse level high-passed with rncc, so that the
      // vertebra's edges lead rather than the heart's bulk (BENCHMARKS.md, "Follow the target"):
      // on the thoracic clinical scene MI's coarse pass took up a set-up 6-8 mm superior with a
      // 5.6-degree x rotation, which moved the heart 8 mm.
      RegistrationPass shift{"quadratic-neighbour", 1.5, 4, 5.0, 1.0, 3000, measure, kRobustHighPassMm};
      shift.translations_only = true;
      plan.passes.insert(plan.passes.begin(), shift);
    }
  } else if (name == "pyramid") {
    plan.passes = {{"quadratic-neighbour", 1.5, 4, 5.0, 0.5, 3000, ""},
                   {"quadratic-neighbour", 0.0, 4, 1.0, 0.25, 3000, ""},
                   {"quadratic-neighbour", 0.0, 1, 0.25, 0.25, 3000, ""}};
  } else if (name == "warm-robust" || name == "warm-robust-ncc") {
    const std::string measure = name == "warm-robust" ? "rncc" : "ncc";
    plan.passes = {{"quadratic-neighbour", 0.0, 2, 1.0, 0.25, 400, measure, kRobustHighPassMm},
                   {"quadratic-neighbour", 0.0, 1, 0.25, 0.1, 200, measure, kRobustHighPassMm}};
  } else if (name == "warm-robust-fast") {
    // warm-robust's measure on 8 x 8 binned images (1 -> 0.25 mm), then 0.25 mm probes on 2 x 2
    // binned ones until they settle: 4.6 ms median on the lumbar clinical scene at warm-robust's
    // mean TRE, where warm-robust takes 31 ms (BENCHMARKS.md, "warm-robust at a seventh"). Not
    // the clinical rooms' default: commissioned with it, the thoracic clinical and clinical
    // phantom scenes' floors rejected 5.94 % of held-out right results (5 % allowed).
    plan.passes = {{"quadratic-neighbour", 0.0, 8, 1.0, 0.25, 400, "rncc", kRobustHighPassMm},
                   {"quadratic-neighbour", 0.0, 2, 0.25, 0.25, 200, "rncc", kRobustHighPassMm}};
  } else {
    std::string known;
    for (const auto& n : registration_plan_names()) known += (known.empty() ? "" : ", ") + n;
    return invalid_argument("unknown registration plan '" + name + "' (known: " + known + ")");
  }
  return plan;
}

}  // namespace lftrack::tracking
