#include "lftrack/tracking/optimizer.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <limits>
#include <optional>
#include <random>

namespace lftrack::tracking {

double budget_now_ms(const BudgetClock* clock) {
  if (clock != nullptr) return clock->now_ms();
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

namespace {

// Evaluation bookkeeping shared by the optimizers: scaled coordinates y (x = start + scale .* y),
// budget, best point, trace.
class Search {
 public:
  Search(CostFunction& cost, const Vector6d& start, const OptimizerSettings& settings, const OptimizerBudget& budget)
      : cost_(cost), start_(start), settings_(settings), budget_(budget), t0_ms_(now_ms()) {
    if (settings.record_trace) result_.trace.reserve(256);
  }

  Vector6d to_x(const Vector6d& y) const { return start_ + settings_.scale.cwiseProduct(y); }
  double now_ms() const { return budget_now_ms(budget_.clock); }
  double elapsed_ms() const { return now_ms() - t0_ms_; }
  // True while another batch of `n` evaluations fits the budget. The time budget bounds when the
  // search ends, not only when its last batch starts: a batch that would end past it, at the mean
  // wall time per evaluation of this search's batches after its first, is not started. Without
  // this a 13-evaluation batch begun just inside a 20 ms budget ran to 33 ms and over a 30 Hz
  // loop's period. The first batch (the start point) is left out of the estimate: it alone pays
  // one-time costs (the first touch of a level's images, page faults in a mapped light field), and
  // one slow evaluation must not end a registration that has most of its budget left. Between
  // the first batch and the next, the budget's priors stand in for the estimate (what earlier
  // searches of the same cost measured; without them the second batch always started, and a
  // registration's last pass overran a 30 Hz period with its batch of 13): the smaller of their
  // time per evaluation and this search's first batch's time scaled by their ratio of a later
  // batch's time to the first's, so that a prior time from a slower spell cannot refuse every
  // later batch (only a search that runs one measures the time again).
  bool can_evaluate(int n) {
    if (result_.evaluations + n > budget_.max_evaluations) {
      stop_ = OptimizerStop::kEvaluationBudget;
      return false;
    }
    const double elapsed = elapsed_ms();
    double per_evaluation_ms = measured_ms_per_evaluation(elapsed);
    const auto known = [](double v) { return std::isfinite(v) && v > 0; };
    const bool timed = result_.evaluations > first_batch_evaluations_;
    if (!timed && first_batch_evaluations_ > 0 && known(budget_.prior_ms_per_evaluation)) {
      const double ratio =
          known(budget_.prior_later_to_first_batch) ? std::min(1.0, budget_.prior_later_to_first_batch) : 1.0;
      per_evaluation_ms = std::min(budget_.prior_ms_per_evaluation, first_batch_ms_per_evaluation() * ratio);
    }
    if (elapsed >= budget_.max_ms || elapsed + n * per_evaluation_ms > budget_.max_ms) {
      stop_ = OptimizerStop::kTimeBudget;
      return false;
    }
    return true;
  }
  // Evaluates points given in scaled coordinates; non-finite costs become +infinity.
  void evaluate(const Vector6d* ys, int n, double* out) {
    for (int i = 0; i < n; ++i) xs_[i] = to_x(ys[i]);
    cost_.cost_batch(xs_.data(), n, out);
    if (result_.evaluations == 0) {
      first_batch_evaluations_ = n;
      first_batch_end_ms_ = elapsed_ms();
    }
    result_.evaluations += n;
    for (int i = 0; i < n; ++i) {
      if (!std::isfinite(out[i])) out[i] = std::numeric_limits<double>::infinity();
      if (out[i] < best_cost_) {
        best_cost_ = out[i];
        best_y_ = ys[i];
      }
    }
  }
  void checkpoint() {
    if (settings_.record_trace) result_.trace.push_back({result_.evaluations, best_cost_, to_x(best_y_)});
  }
  OptimizerResult finish(OptimizerStop converged_or_not) {
    result_.x = to_x(best_y_);
    result_.cost = best_cost_;
    result_.elapsed_ms = elapsed_ms();
    result_.first_batch_ms_per_evaluation = first_batch_ms_per_evaluation();
    result_.ms_per_evaluation = measured_ms_per_evaluation(result_.elapsed_ms);
    result_.stop = stop_.value_or(converged_or_not);
    if (result_.evaluations > 0 && !std::isfinite(best_cost_)) result_.stop = OptimizerStop::kNonFinite;
    return std::move(result_);
  }
  double best_cost() const { return best_cost_; }
  const Vector6d& best_y() const { return best_y_; }
  const OptimizerSettings& settings() const { return settings_; }

  static constexpr int kMaxBatch = 64;

 private:
  double first_batch_ms_per_evaluation() const {
    return first_batch_evaluations_ > 0 ? first_batch_end_ms_ / first_batch_evaluations_ : 0.0;
  }
  // The mean wall time per evaluation of the batches after the first, up to `elapsed` (0: none).
  double measured_ms_per_evaluation(double elapsed) const {
    const int timed = result_.evaluations - first_batch_evaluations_;
    return timed > 0 ? std::max(0.0, elapsed - first_batch_end_ms_) / timed : 0.0;
  }

  CostFunction& cost_;
  Vector6d start_;
  OptimizerSettings settings_;
  OptimizerBudget budget_;
  double t0_ms_;  // on now_ms()'s clock
  OptimizerResult result_;
  std::optional<OptimizerStop> stop_;
  int first_batch_evaluations_ = 0;  // the first batch, left out of the time estimate
  double first_batch_end_ms_ = 0;
  double best_cost_ = std::numeric_limits<double>::infinity();
  Vector6d best_y_ = Vector6d::Zero();
  std::array<Vector6d, kMaxBatch> xs_;
};

// The 12 points centre +- step along each parameter, in the order (+0, -0, +1, -1, ...).
void make_neighbours(const Vector6d& centre, double step, std::array<Vector6d, 12>* neighbours) {
  for (int i = 0; i < 6; ++i) {
    (*neighbours)[std::size_t(2 * i)] = centre;
    (*neighbours)[std::size_t(2 * i)](i) += step;
    (*neighbours)[std::size_t(2 * i + 1)] = centre;
    (*neighbours)[std::size_t(2 * i + 1)](i) -= step;
  }
}

// Evaluates the start point; false if the budget allows not even that.
bool evaluate_start(Search& search, Vector6d* centre, double* centre_cost) {
  *centre = Vector6d::Zero();
  if (!search.can_evaluate(1)) return false;
  search.evaluate(centre, 1, centre_cost);
  return true;
}

class BestNeighbour final : public Optimizer {
 public:
  explicit BestNeighbour(OptimizerSettings s) : settings_(std::move(s)) {}
  std::string_view name() const override { return "best-neighbour"; }
  OptimizerResult minimize(CostFunction& cost, const Vector6d& start, const OptimizerBudget& budget) const override {
    Search search(cost, start, settings_, budget);
    Vector6d centre;
    double centre_cost = 0;
    if (!evaluate_start(search, &centre, &centre_cost)) return search.finish(OptimizerStop::kConverged);
    std::array<Vector6d, 12> neighbours;
    std::array<double, 12> costs;
    for (double step = settings_.initial_step_mm; step >= settings_.final_step_mm * (1 - 1e-9); step *= 0.5) {
      for (;;) {
        make_neighbours(centre, step, &neighbours);
        if (!search.can_evaluate(12)) return search.finish(OptimizerStop::kConverged);
        search.evaluate(neighbours.data(), 12, costs.data());
        const int best = int(std::min_element(costs.begin(), costs.end()) - costs.begin());
        search.checkpoint();
        if (!(costs[best] < centre_cost)) break;
        centre = neighbours[best];
        centre_cost = costs[best];
      }
    }
    return search.finish(OptimizerStop::kConverged);
  }

 private:
  OptimizerSettings settings_;
};

class Decoupled final : public Optimizer {
 public:
  explicit Decoupled(OptimizerSettings s) : settings_(std::move(s)) {}
  std::string_view name() const override { return "decoupled"; }
  OptimizerResult minimize(CostFunction& cost, const Vector6d& start, const OptimizerBudget& budget) const override {
    static constexpr std::array<std::array<int, 2>, 3> kPairs{{{0, 4}, {1, 5}, {2, 3}}};
    Search search(cost, start, settings_, budget);
    Vector6d centre;
    double centre_cost = 0;
    if (!evaluate_start(search, &centre, &centre_cost)) return search.finish(OptimizerStop::kConverged);
    double step = settings_.initial_step_mm;
    while (step >= settings_.final_step_mm * (1 - 1e-9)) {
      bool improved = false;
      for (const auto& pair : kPairs) {
        // Five costs: the centre (known) and +-step along each parameter of the pair.
        std::array<Vector6d, 4> samples;
        std::array<double, 4> costs;
        for (int k = 0; k < 2; ++k) {
          samples[2 * k] = centre;
          samples[2 * k](pair[k]) += step;
          samples[2 * k + 1] = centre;
          samples[2 * k + 1](pair[k]) -= step;
        }
        if (!search.can_evaluate(5)) return search.finish(OptimizerStop::kConverged);
        search.evaluate(samples.data(), 4, costs.data());
        // Separable quadratic through the five: per axis, slope and curvature; jump to its
        // minimum, at most two steps away (or one step downhill where it is not convex).
        Vector6d jump = centre;
        for (int k = 0; k < 2; ++k) {
          const double plus = costs[2 * k], minus = costs[2 * k + 1];
          const double slope = (plus - minus) / (2 * step);
          const double curvature = (plus + minus - 2 * centre_cost) / (step * step);
          double move = 0;
          if (std::isfinite(slope) && curvature > 0) {
            move = std::clamp(-slope / curvature, -2 * step, 2 * step);
          } else if (plus < centre_cost || minus < centre_cost) {
            move = plus < minus ? step : -step;
          }
          jump(pair[k]) += move;
        }
        double jump_cost = std::numeric_limits<double>::infinity();
        if (jump != centre) search.evaluate(&jump, 1, &jump_cost);
        // Move to the best of the jump and the samples.
        Vector6d best = jump;
        double best_cost = jump_cost;
        for (int i = 0; i < 4; ++i) {
          if (costs[i] < best_cost) {
            best_cost = costs[i];
            best = samples[i];
          }
        }
        if (best_cost < centre_cost) {
          const double moved = (best - centre).cwiseAbs().maxCoeff();
          centre = best;
          centre_cost = best_cost;
          if (moved > 0.25 * step) improved = true;  // a negligible change does not hold the step
        }
        search.checkpoint();
      }
      if (!improved) step *= 0.5;
    }
    return search.finish(OptimizerStop::kConverged);
  }

 private:
  OptimizerSettings settings_;
};

class QuadraticNeighbour final : public Optimizer {
 public:
  explicit QuadraticNeighbour(OptimizerSettings s) : settings_(std::move(s)) {}
  std::string_view name() const override { return "quadratic-neighbour"; }
  OptimizerResult minimize(CostFunction& cost, const Vector6d& start, const OptimizerBudget& budget) const override {
    Search search(cost, start, settings_, budget);
    Vector6d centre;
    double centre_cost = 0;
    if (!evaluate_start(search, &centre, &centre_cost)) return search.finish(OptimizerStop::kConverged);
    std::array<Vector6d, 12> neighbours;
    std::array<double, 12> costs;
    const int axes = settings_.translations_only ? 3 : 6;  // translations are x(0..2)
    const int probes = 2 * axes;
    for (double step = settings_.initial_step_mm; step >= settings_.final_step_mm * (1 - 1e-9);) {
      make_neighbours(centre, step, &neighbours);
      if (!search.can_evaluate(probes + 1)) return search.finish(OptimizerStop::kConverged);
      search.evaluate(neighbours.data(), probes, costs.data());
      // Per-axis parabola through (-step, 0, +step): Newton step on the diagonal model.
      Vector6d jump = centre;
      for (int i = 0; i < axes; ++i) {
        const double plus = costs[std::size_t(2 * i)], minus = costs[std::size_t(2 * i + 1)];
        const double slope = (plus - minus) / (2 * step);
        const double curvature = (plus + minus - 2 * centre_cost) / (step * step);
        double move = 0;
        if (std::isfinite(slope) && std::isfinite(curvature) && curvature > 0)
          move = std::clamp(-slope / curvature, -2 * step, 2 * step);
        else if (plus < centre_cost || minus < centre_cost)
          move = plus < minus ? step : -step;
        jump(i) += move;
      }
      double jump_cost = std::numeric_limits<double>::infinity();
      if (jump != centre) search.evaluate(&jump, 1, &jump_cost);
      const int best = int(std::min_element(costs.begin(), costs.begin() + probes) - costs.begin());
      search.checkpoint();
      const bool jump_wins = jump_cost <= costs[best];
      const double candidate_cost = jump_wins ? jump_cost : costs[best];
      // The model's minimum lies within the tolerance of the centre, and no neighbour says otherwise.
      const bool converged = settings_.tolerance_mm > 0 && (jump - centre).cwiseAbs().maxCoeff() <= settings_.tolerance_mm &&
                             (jump_wins || !(candidate_cost < centre_cost));
      if (candidate_cost < centre_cost) {
        const Vector6d next = jump_wins ? jump : neighbours[best];
        const double moved = (next - centre).cwiseAbs().maxCoeff();
        centre = next;
        centre_cost = candidate_cost;
        if (converged) break;
        if (moved > 0.5 * step) continue;  // still travelling at this step
      }
      if (converged) break;
      step *= 0.5;  // settled to within half a step: refine
    }
    return search.finish(OptimizerStop::kConverged);
  }

 private:
  OptimizerSettings settings_;
};

// CMA-ES with rank-one and rank-mu updates (Hansen, "The CMA Evolution Strategy: A Tutorial"),
// in scaled coordinates, sigma starting at the initial step.
class Cmaes final : public Optimizer {
 public:
  explicit Cmaes(OptimizerSettings s) : settings_(std::move(s)) {}
  std::string_view name() const override { return "cmaes"; }
  OptimizerResult minimize(CostFunction& cost, const Vector6d& start, const OptimizerBudget& budget) const override {
    constexpr int n = 6;
    int lambda = settings_.population > 0 ? settings_.population : 4 + int(std::floor(3 * std::log(double(n))));
    lambda = std::clamp(lambda + (lambda % 2), 4, Search::kMaxBatch);
    const int mu = lambda / 2;
    std::vector<double> w(mu);
    for (int i = 0; i < mu; ++i) w[i] = std::log(mu + 0.5) - std::log(i + 1.0);
    const double wsum = std::accumulate(w.begin(), w.end(), 0.0);
    double w2 = 0;
    for (double& wi : w) {
      wi /= wsum;
      w2 += wi * wi;
    }
    const double mueff = 1.0 / w2;
    const double cc = (4 + mueff / n) / (n + 4 + 2 * mueff / n);
    const double cs = (mueff + 2) / (n + mueff + 5);
    const double c1 = 2 / ((n + 1.3) * (n + 1.3) + mueff);
    const double cmu = std::min(1 - c1, 2 * (mueff - 2 + 1 / mueff) / ((n + 2) * (n + 2) + mueff));
    const double damps = 1 + 2 * std::max(0.0, std::sqrt((mueff - 1) / (n + 1)) - 1) + cs;
    const double chi_n = std::sqrt(double(n)) * (1 - 1.0 / (4 * n) + 1.0 / (21.0 * n * n));

    Search search(cost, start, settings_, budget);
    std::mt19937_64 rng(settings_.seed);
    std::normal_distribution<double> normal(0.0, 1.0);
    Vector6d mean = Vector6d::Zero(), ps = Vector6d::Zero(), pc = Vector6d::Zero();
    Eigen::Matrix<double, 6, 6> C = Eigen::Matrix<double, 6, 6>::Identity();
    double sigma = settings_.initial_step_mm;
    {
      double c0;
      if (!search.can_evaluate(1)) return search.finish(OptimizerStop::kConverged);
      search.evaluate(&mean, 1, &c0);
    }
    std::array<Vector6d, Search::kMaxBatch> ys;
    std::array<double, Search::kMaxBatch> costs;
    std::array<int, Search::kMaxBatch> order;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig;
    for (int generation = 0;; ++generation) {
      eig.compute(C);
      const Vector6d d = eig.eigenvalues().cwiseMax(1e-20).cwiseSqrt();
      const Eigen::Matrix<double, 6, 6> B = eig.eigenvectors();
      if (sigma * d.maxCoeff() < settings_.final_step_mm) break;
      if (!search.can_evaluate(lambda)) break;
      for (int k = 0; k < lambda; ++k) {
        Vector6d z;
        for (int i = 0; i < n; ++i) z(i) = normal(rng);
        ys[k] = mean + sigma * (B * d.asDiagonal() * z);
      }
      search.evaluate(ys.data(), lambda, costs.data());
      std::iota(order.begin(), order.begin() + lambda, 0);
      std::sort(order.begin(), order.begin() + lambda, [&](int a, int b) { return costs[a] < costs[b]; });
      const Vector6d old_mean = mean;
      mean.setZero();
      for (int i = 0; i < mu; ++i) mean += w[i] * ys[order[i]];
      const Vector6d step = (mean - old_mean) / sigma;
      const Vector6d c_inv_sqrt_step = B * d.cwiseInverse().asDiagonal() * B.transpose() * step;
      ps = (1 - cs) * ps + std::sqrt(cs * (2 - cs) * mueff) * c_inv_sqrt_step;
      const double hsig_threshold = (1.4 + 2.0 / (n + 1)) * chi_n *
                                    std::sqrt(1 - std::pow(1 - cs, 2.0 * (generation + 1)));
      const bool hsig = ps.norm() < hsig_threshold;
      pc = (1 - cc) * pc + (hsig ? std::sqrt(cc * (2 - cc) * mueff) : 0.0) * step;
      Eigen::Matrix<double, 6, 6> rank_mu = Eigen::Matrix<double, 6, 6>::Zero();
      for (int i = 0; i < mu; ++i) {
        const Vector6d dy = (ys[order[i]] - old_mean) / sigma;
        rank_mu += w[i] * dy * dy.transpose();
      }
      C = (1 - c1 - cmu) * C + c1 * (pc * pc.transpose() + (hsig ? 0.0 : cc * (2 - cc)) * C) + cmu * rank_mu;
      C = 0.5 * (C + C.transpose());
      sigma *= std::exp((cs / damps) * (ps.norm() / chi_n - 1));
      if (!std::isfinite(sigma) || sigma > 1e6) break;
      search.checkpoint();
    }
    return search.finish(OptimizerStop::kConverged);
  }

 private:
  OptimizerSettings settings_;
};

}  // namespace

const char* to_string(OptimizerStop stop) {
  switch (stop) {
    case OptimizerStop::kConverged:
      return "converged";
    case OptimizerStop::kEvaluationBudget:
      return "evaluation budget";
    case OptimizerStop::kTimeBudget:
      return "time budget";
    case OptimizerStop::kNonFinite:
      return "no finite cost";
  }
  return "?";
}

std::vector<std::string> optimizer_names() {
  return {"best-neighbour", "quadratic-neighbour", "decoupled", "cmaes"};
}

Result<std::unique_ptr<Optimizer>> make_optimizer(std::string_view name, const OptimizerSettings& settings) {
  if (!settings.scale.allFinite() || (settings.scale.array() <= 0).any())
    return invalid_argument("optimizer: every parameter scale must be positive and finite");
  if (!(settings.final_step_mm > 0) || !(settings.initial_step_mm >= settings.final_step_mm) ||
      !std::isfinite(settings.initial_step_mm))
    return invalid_argument("optimizer: steps must satisfy initial >= final > 0");
  if (!std::isfinite(settings.tolerance_mm) || settings.tolerance_mm < 0 ||
      settings.tolerance_mm > settings.initial_step_mm)
    return invalid_argument("optimizer: the tolerance must be from 0 (off) to the initial step");
  if (settings.translations_only && name != "quadratic-neighbour")
    return invalid_argument("optimizer: only quadratic-neighbour moves the translations alone, not " +
                            std::string(name));
  if (name == "best-neighbour") return std::unique_ptr<Optimizer>(new BestNeighbour(settings));
  if (name == "quadratic-neighbour") return std::unique_ptr<Optimizer>(new QuadraticNeighbour(settings));
  if (name == "decoupled") return std::unique_ptr<Optimizer>(new Decoupled(settings));
  if (name == "cmaes") return std::unique_ptr<Optimizer>(new Cmaes(settings));
  std::string known;
  for (const auto& n : optimizer_names()) known += (known.empty() ? "" : ", ") + n;
  return invalid_argument("unknown optimizer '" + std::string(name) + "' (known: " + known + ")");
}

}  // namespace lftrack::tracking
