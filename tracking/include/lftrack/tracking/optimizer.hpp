#pragma once
// Optimizers over the pose 6-vector delta = (t [mm], omega [rad]) (DESIGN.md, "Frames"). They
// minimise a cost (registration passes minus the similarity) and never see Euler angles.
//
// Every optimizer works in scaled units: parameter i moves by `step * scale[i]`, where `scale[i]`
// is what moves the projected ROI voxels by 1 mm on average on the detectors (so one step
// disturbs the images equally for every parameter, PAPERS.md paper 1). Steps are in those
// "projected millimetres". Chosen by name through make_optimizer(); one test runs them all on the
// same problems.

#include <chrono>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {

// What an optimizer minimises. cost_batch() may evaluate its points in parallel; both must be
// deterministic (the same x gives the same cost) and return a finite value or +infinity.
class CostFunction {
 public:
  virtual ~CostFunction() = default;
  virtual double cost(const Vector6d& x) = 0;
  // out[i] = cost(xs[i]) for i < n; the default evaluates them one after another.
  virtual void cost_batch(const Vector6d* xs, int n, double* out) {
    for (int i = 0; i < n; ++i) out[i] = cost(xs[i]);
  }
};

// The monotonic time (ms, any origin) that a search's time budget is counted in. The default is
// the steady clock. A test gives a virtual clock that its cost function advances, so that whether
// a batch fits the budget is decided the same way on a loaded machine as on an idle one.
class BudgetClock {
 public:
  virtual ~BudgetClock() = default;
  virtual double now_ms() const = 0;
};

// Now in ms on `clock`, or on std::chrono::steady_clock where it is null (any origin).
double budget_now_ms(const BudgetClock* clock);

struct OptimizerBudget {
  int max_evaluations = 5000;
  double max_ms = 1e12;  // wall time, on `clock`
  const BudgetClock* clock = nullptr;  // null: std::chrono::steady_clock; must outlive the search
  // What earlier searches of the same cost measured (OptimizerResult's times), to judge whether
  // the batch after the first fits max_ms before this search has timed one of its own (later
  // batches go by its own times). That batch's time per evaluation is taken as the smaller of
  // prior_ms_per_evaluation and this search's first batch's time per evaluation times
  // prior_later_to_first_batch (at most 1: a later batch is spread over as many threads or more),
  // so a prior from a slower spell gives way as soon as a first batch runs faster. A value that is
  // not a positive finite number is unknown: an unknown ratio counts as 1, and with no prior time
  // the batch always starts.
  double prior_ms_per_evaluation = 0;
  double prior_later_to_first_batch = 0;
};

struct OptimizerSettings {
  Vector6d scale = Vector6d::Ones();  // parameter units per projected mm
  double initial_step_mm = 2.0;       // projected mm
  double final_step_mm = 0.1;
  // quadratic-neighbour: converged once an iteration's parabola jump moves no parameter by more
  // than this (projected mm) and nothing beats the jump, however large the step still is: the
  // model then puts the minimum within this of the centre. 0: off (halve down to the final step).
  double tolerance_mm = 0;
  // quadratic-neighbour: probe the three translations only; the rotations stay at the start's
  // (a cold set-up's first pass: a shift far along one axis is found before a rotation can
  // imitate part of it). make_optimizer refuses it for the other optimizers.
  bool translations_only = false;
  // cmaes: population (0: 4 + 3 ln 6 rounded up to even), and the RNG seed.
  int population = 0;
  std::uint64_t seed = 1;
  bool record_trace = false;
};

struct OptimizerTracePoint {
  int evaluations = 0;
  double cost = 0;
  Vector6d x = Vector6d::Zero();
};

enum class OptimizerStop { kConverged, kEvaluationBudget, kTimeBudget, kNonFinite };
const char* to_string(OptimizerStop stop);

struct OptimizerResult {
  Vector6d x = Vector6d::Zero();  // best point found
  double cost = 0;
  int evaluations = 0;
  double elapsed_ms = 0;
  // The mean wall time per evaluation of the first batch and of the batches after it (ms; 0: none
  // ran): what a later search of the same cost may take as its OptimizerBudget's priors.
  double first_batch_ms_per_evaluation = 0;
  double ms_per_evaluation = 0;
  OptimizerStop stop = OptimizerStop::kConverged;
  std::vector<OptimizerTracePoint> trace;  // the best point after each iteration (if asked)
};

class Optimizer {
 public:
  virtual ~Optimizer() = default;
  virtual std::string_view name() const = 0;
  virtual OptimizerResult minimize(CostFunction& cost, const Vector6d& start, const OptimizerBudget& budget) const = 0;
};

// Names accepted by make_optimizer, in a stable order:
//   best-neighbour  Studholme's best-neighbour search: the 12 neighbours x +- step * scale[i],
//                   move to the best while it improves, then halve the step down to the final one.
//   quadratic-neighbour  the same 12 neighbours, plus a jump to the minimum of the per-axis
//                   parabolas through them (at most two steps per axis); moves to the better of
//                   the jump and the best neighbour; halves the step once a move is shorter than
//                   half a step. Fewer evaluations than best-neighbour for the same end point.
//                   With a tolerance, stops as soon as the jump is that short and nothing beats it.
//   decoupled       paper 3: pairs {tx, wy}, {ty, wz}, {tz, wx} (weakly coupled for views about
//                   the room's z axis), five costs each, a separable quadratic fit, a jump to its
//                   minimum (at most two steps away); halve the step when no pair improves.
//   cmaes           CMA-ES (Hansen) from the initial step as sigma, for the wide-range cold start;
//                   stops when sigma falls below the final step.
std::vector<std::string> optimizer_names();
Result<std::unique_ptr<Optimizer>> make_optimizer(std::string_view name, const OptimizerSettings& settings);

}  // namespace lftrack::tracking
