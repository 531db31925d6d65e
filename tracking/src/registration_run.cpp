// Running a registration plan (registration.hpp): the optimizer's cost over one pass's image
// level, the passes' time priors, prepare_plan() and run(). The levels, frames, references and
// scores the passes evaluate are registration.cpp's.

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "lftrack/tracking/registration.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::tracking {

// The optimizer's view of one pass: x = delta from the start pose. It keeps the per-view scores
// of the best candidate so far (the lowest cost, the first of equals, as the optimizer's Search
// keeps its best point), so that a pass on the originals needs no evaluation of its result.
class Registration::Cost final : public CostFunction {
 public:
  static constexpr int kMaxViews = 4;

  Cost(Registration& r, const Pose& start, int measure, int level)
      : r_(r), start_(start), measure_(measure), level_(level) {}
  double cost(const Vector6d& x) override {
    double out = 0;
    cost_batch(&x, 1, &out);
    return out;
  }
  void cost_batch(const Vector6d* xs, int n, double* out) override {
    for (int first = 0; first < n; first += kMaxBatch) evaluate(xs + first, std::min(n - first, kMaxBatch), out + first);
  }
  Pose pose(const Vector6d& x) const {
    return apply_delta(start_, PoseDelta::from_vector(x), r_.setup_.origin_room_mm);
  }
  // The best candidate's cost and per-view scores (+infinity and nothing before a finite cost).
  double best_cost() const { return best_cost_; }
  const double* best_view_scores() const { return best_scores_.data(); }

 private:
  static constexpr int kMaxBatch = 64;

  // Spreads (candidate, view) pairs over the pool one at a time, so a batch of one still uses
  // two threads and a worker that wakes late takes what is left rather than half the batch.
  // Each thread scores with its own slot's scratch; every slot holds the same prepared
  // references, so a score does not depend on which thread computed it.
  void evaluate(const Vector6d* xs, int n, double* out) {
    const int views = static_cast<int>(r_.setup_.views.size());
    const int slots = static_cast<int>(r_.slots_.size());
    const int tasks = n * views;
    for (int i = 0; i < n; ++i) {
      poses_[i] = pose(xs[i]);
      inside_[i] = r_.inside_search_region(poses_[i]);
    }
    if (r_.pool_ == nullptr || slots < 2 || tasks < 2) {
      for (int t = 0; t < tasks; ++t)
        view_scores_[t] = inside_[t / views] ? r_.view_score(0, measure_, level_, poses_[t / views], t % views) : 0.0;
    } else {
      ThreadPool& pool = *r_.pool_;
      pool.parallel_for(tasks, 1, [&](int begin, int end) {
        const int slot = pool.thread_index();
        for (int t = begin; t < end; ++t) {
          const int i = t / views;
          view_scores_[t] = inside_[i] ? r_.view_score(slot, measure_, level_, poses_[i], t % views) : 0.0;
        }
      });
    }
    for (int i = 0; i < n; ++i) {
      out[i] = inside_[i] ? r_.combine(poses_[i], &view_scores_[i * views])
                          : std::numeric_limits<double>::infinity();
      if (out[i] < best_cost_) {
        best_cost_ = out[i];
        std::copy_n(&view_scores_[i * views], views, best_scores_.begin());
      }
    }
  }

  Registration& r_;
  Pose start_;
  int measure_, level_;
  std::array<Pose, kMaxBatch> poses_;
  std::array<bool, kMaxBatch> inside_{};
  std::array<double, kMaxBatch * kMaxViews> view_scores_{};
  double best_cost_ = std::numeric_limits<double>::infinity();
  std::array<double, kMaxViews> best_scores_{};
};

void Registration::RecentMedian::add(double value) {
  if (!std::isfinite(value) || value <= 0) return;
  values_[std::size_t(next_)] = value;
  next_ = (next_ + 1) % int(values_.size());
  count_ = std::min(count_ + 1, int(values_.size()));
}

double Registration::RecentMedian::median() const {
  if (count_ == 0) return 0.0;
  // Insertion sort of the few kept (std::sort over part of the array trips GCC 12's bounds check).
  std::array<double, 5> sorted{};
  for (int i = 0; i < count_; ++i) {
    int j = i;
    for (; j > 0 && sorted[std::size_t(j - 1)] > values_[std::size_t(i)]; --j)
      sorted[std::size_t(j)] = sorted[std::size_t(j - 1)];
    sorted[std::size_t(j)] = values_[std::size_t(i)];
  }
  return sorted[std::size_t(count_ - 1) / 2];  // the lower of two middles
}

Result<PreparedPlan> Registration::prepare_plan(const RegistrationPlan& plan, bool record_trace) {
  if (plan.passes.empty()) return invalid_argument("registration: the plan has no passes");
  if (plan.passes.size() > kMaxRegistrationPasses)
    return invalid_argument("registration: a plan has at most " + std::to_string(kMaxRegistrationPasses) + " passes");
  PreparedPlan prepared;
  prepared.owner = this;
  prepared.plan = plan;
  prepared.record_trace = record_trace;
  for (const RegistrationPass& pass : plan.passes) {
    // A pass binned past what the windows allow (fewer than 4 x 4 pixels) runs at the coarsest
    // binning they do allow, so a plan made for larger windows (warm's 8 x 8 pass) still runs on
    // a small one. Binnings outside 1..16 stay as given, for level_for to refuse.
    int bin = pass.bin;
    while (bin > 1 && bin <= 16 && view_too_small_for(bin) != nullptr) bin /= 2;
    auto level = level_for({pass.blur_sigma_mm, bin, pass.highpass_sigma_mm});
    if (!level.ok()) return level.status();
    OptimizerSettings settings;
    settings.scale = scales_;
    settings.initial_step_mm = pass.initial_step_mm;
    settings.final_step_mm = pass.final_step_mm;
    settings.tolerance_mm = pass.tolerance_mm;
    settings.translations_only = pass.translations_only;
    settings.record_trace = record_trace;
    auto optimizer = make_optimizer(pass.optimizer, settings);
    if (!optimizer.ok()) return optimizer.status();
    auto measure = measure_index(pass.similarity);
    if (!measure.ok()) return measure.status();
    prepared.optimizers.push_back(std::move(*optimizer));
    prepared.levels.push_back(*level);
    prepared.measures.push_back(*measure);
  }
  return prepared;
}

Result<RegistrationResult> Registration::run(const Pose& start, const RegistrationPlan& plan,
                                             bool record_trace) {
  auto prepared = prepare_plan(plan, record_trace);
  if (!prepared.ok()) return prepared.status();
  RegistrationResult result;
  LFTRACK_RETURN_IF_ERROR(run(start, *prepared, plan.max_ms, &result));
  return result;
}

Status Registration::run(const Pose& start, const PreparedPlan& prepared, double max_ms,
                         RegistrationResult* result, const BudgetClock* clock) {
  if (!frames_set_) return failed_precondition("registration: no frames (call set_frames first)");
  if (!start.matrix().allFinite()) return invalid_argument("registration: the start pose is not finite");
  if (prepared.optimizers.empty() || prepared.optimizers.size() != prepared.plan.passes.size() ||
      prepared.levels.size() != prepared.optimizers.size() || prepared.measures.size() != prepared.optimizers.size())
    return invalid_argument("registration: the plan was not prepared");
  if (prepared.owner != this)
    return invalid_argument("registration: the plan was prepared by another registration");
  for (std::size_t p = 0; p < prepared.measures.size(); ++p)
    if (prepared.measures[p] < 0 || std::size_t(prepared.measures[p]) >= measure_names_.size() ||
        prepared.levels[p] < 0 || std::size_t(prepared.levels[p]) >= levels_.size())
      return invalid_argument("registration: the plan was not prepared by this registration");
  const double t0_ms = budget_now_ms(clock);
  auto ms_since = [clock](double since_ms) { return budget_now_ms(clock) - since_ms; };
  const double budget_ms = std::min(max_ms, prepared.plan.max_ms);
  result->evaluations = 0;
  result->cost = 0;
  result->stop = OptimizerStop::kConverged;
  result->fiducial_distance_mm = -1;
  result->trace.clear();
  result->passes.clear();
  result->passes.reserve(kMaxRegistrationPasses);  // once per result: every plan fits
  Pose current = start;
  // The result's per-view scores when the last pass ran on the originals with the setup's measure
  // (its best candidate is the result); otherwise they are evaluated at the result below.
  std::array<double, Cost::kMaxViews> result_scores{};
  bool have_result_scores = false;
  // Every level the plan uses and the originals (which score the result), made once per set of
  // frames, before any pass: a run cut short by its budget still leaves them all prepared, so no
  // later run prepares (and allocates) one for the first time. Each one's time is charged to the
  // first pass that uses it (the originals', if no pass uses them, to the first pass); all of it
  // counts against the budget.
  std::array<double, kMaxRegistrationPasses> prepare_ms{};
  for (std::size_t p = 0; p < prepared.optimizers.size(); ++p) {
    const double level_t0 = budget_now_ms(clock);
    LFTRACK_RETURN_IF_ERROR(prepare_level(prepared.measures[p], prepared.levels[p]));
    prepare_ms[p] = ms_since(level_t0);
  }
  {
    const double level_t0 = budget_now_ms(clock);
    LFTRACK_RETURN_IF_ERROR(prepare_level(0, 0));
    prepare_ms[0] += ms_since(level_t0);
  }
  for (std::size_t p = 0; p < prepared.optimizers.size(); ++p) {
    const double pass_t0 = budget_now_ms(clock);
    OptimizerBudget budget;
    budget.max_evaluations = prepared.plan.passes[p].max_evaluations;
    budget.max_ms = budget_ms - ms_since(t0_ms);
    budget.clock = clock;
    PassTimes& times = pass_times_[std::size_t(prepared.measures[p])][std::size_t(prepared.levels[p])];
    budget.prior_ms_per_evaluation = times.ms_per_evaluation.median();
    budget.prior_later_to_first_batch = times.later_to_first_batch.median();
    Cost cost(*this, current, prepared.measures[p], prepared.levels[p]);
    OptimizerResult r = prepared.optimizers[p]->minimize(cost, Vector6d::Zero(), budget);
    if (r.ms_per_evaluation > 0 && r.first_batch_ms_per_evaluation > 0) {
      times.ms_per_evaluation.add(r.ms_per_evaluation);
      times.later_to_first_batch.add(r.ms_per_evaluation / r.first_batch_ms_per_evaluation);
    }
    current = cost.pose(r.x);
    have_result_scores = prepared.levels[p] == 0 && prepared.measures[p] == 0 && std::isfinite(r.cost) &&
                         cost.best_cost() == r.cost;
    if (have_result_scores)
      std::copy_n(cost.best_view_scores(), setup_.views.size(), result_scores.begin());
    result->evaluations += r.evaluations;
    result->cost = r.cost;
    result->stop = r.stop;
    result->passes.push_back({r.evaluations, prepare_ms[p] + ms_since(pass_t0), r.stop});
    for (const OptimizerTracePoint& point : r.trace) {
      OptimizerTracePoint q = point;
      q.evaluations += result->evaluations - r.evaluations;
      q.x = delta_between(start, cost.pose(point.x), setup_.origin_room_mm).as_vector();
      result->trace.push_back(q);
    }
    // A pass that found nothing finite ends the plan, except a translations-only pass: from a start
    // whose rotation lies outside the search region every shift costs +infinity, and the next
    // pass, which moves the rotations too, starts from the unchanged pose.
    if (r.stop == OptimizerStop::kTimeBudget ||
        (r.stop == OptimizerStop::kNonFinite && !prepared.plan.passes[p].translations_only))
      break;
  }
  result->T_room_from_ct = orthonormalized(current);
  result->delta_from_start = delta_between(start, result->T_room_from_ct, setup_.origin_room_mm);
  result->view_similarity.resize(setup_.views.size());
  std::fill(result->view_similarity.begin(), result->view_similarity.end(), 0.0);
  if (have_result_scores) {
    std::copy_n(result_scores.begin(), setup_.views.size(), result->view_similarity.begin());
  } else {
    evaluate(0, 0, 0, result->T_room_from_ct, &result->view_similarity);  // the setup's measure, originals
  }
  if (fiducial_)
    result->fiducial_distance_mm =
        (result->T_room_from_ct * fiducial_->marker_ct_mm - fiducial_->marker_room_mm).norm();
  result->elapsed_ms = ms_since(t0_ms);
  return {};
}

}  // namespace lftrack::tracking
