// Numerical stability at the extremes: optimizers (docs/stability.md, "Optimizers"). Every
// optimizer, on a flat cost, a NaN cost and budgets of zero and one evaluation, returns a finite
// point within its budget, promptly.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "lftrack/tracking/optimizer.hpp"

namespace lftrack::tracking {
namespace {

class CountingCost : public CostFunction {
 public:
  explicit CountingCost(std::function<double(const Vector6d&)> f) : f_(std::move(f)) {}
  double cost(const Vector6d& x) override {
    ++calls;
    return f_(x);
  }
  int calls = 0;

 private:
  std::function<double(const Vector6d&)> f_;
};

std::unique_ptr<Optimizer> make(const std::string& name) {
  OptimizerSettings settings;
  settings.initial_step_mm = 2;
  settings.final_step_mm = 0.1;
  auto o = make_optimizer(name, settings);
  EXPECT_TRUE(o.ok());
  return std::move(o).value();
}

Vector6d start() {
  Vector6d x;
  x << 1, -2, 0.5, 0.01, 0.02, -0.01;
  return x;
}

class OptimizerAtTheExtremes : public ::testing::TestWithParam<std::string> {};

TEST_P(OptimizerAtTheExtremes, FlatCostStaysAtTheStart) {
  CountingCost flat([](const Vector6d&) { return 3.0; });
  const OptimizerResult r = make(GetParam())->minimize(flat, start(), {});
  EXPECT_TRUE(r.x.allFinite());
  EXPECT_EQ(r.cost, 3.0);
  EXPECT_LT((r.x - start()).norm(), 1e-12) << "no move is better than the start";
  EXPECT_LT(r.evaluations, 5000) << "a flat cost converges, it does not run out the budget";
}

TEST_P(OptimizerAtTheExtremes, NanCostsAreNeverChosen) {
  // NaN everywhere but the start, and NaN in half the space around a minimum.
  CountingCost nan_everywhere(
      [](const Vector6d& x) { return (x - start()).norm() < 1e-12 ? 1.0 : std::nan(""); });
  const OptimizerResult a = make(GetParam())->minimize(nan_everywhere, start(), {});
  EXPECT_TRUE(a.x.allFinite());
  EXPECT_FALSE(std::isnan(a.cost));
  EXPECT_LE(a.evaluations, 5000);
  CountingCost half([](const Vector6d& x) { return x(0) > 0.5 ? std::nan("") : x.squaredNorm(); });
  const OptimizerResult b = make(GetParam())->minimize(half, start(), {});
  EXPECT_TRUE(b.x.allFinite());
  ASSERT_FALSE(std::isnan(b.cost));
  EXPECT_LE(b.cost, start().squaredNorm() + 1e-12);
  CountingCost nan_start([](const Vector6d& x) { return x(0) > 0.9 ? std::nan("") : x.squaredNorm(); });
  const OptimizerResult c = make(GetParam())->minimize(nan_start, start(), {});
  EXPECT_TRUE(c.x.allFinite());
  EXPECT_FALSE(std::isnan(c.cost));
}

TEST_P(OptimizerAtTheExtremes, BudgetsOfZeroAndOneEvaluation) {
  for (int budget : {0, 1}) {
    CountingCost bowl([](const Vector6d& x) { return x.squaredNorm(); });
    OptimizerBudget b;
    b.max_evaluations = budget;
    const OptimizerResult r = make(GetParam())->minimize(bowl, start(), b);
    EXPECT_TRUE(r.x.allFinite());
    EXPECT_LE(bowl.calls, std::max(budget, 1)) << "budget " << budget;
    EXPECT_EQ(r.stop, OptimizerStop::kEvaluationBudget) << "budget " << budget;
    EXPECT_LT((r.x - start()).norm(), 1e-12) << "nothing better was seen";
  }
  CountingCost bowl([](const Vector6d& x) { return x.squaredNorm(); });
  OptimizerBudget no_time;
  no_time.max_ms = 0;
  const OptimizerResult r = make(GetParam())->minimize(bowl, start(), no_time);
  EXPECT_TRUE(r.x.allFinite());
  EXPECT_LE(r.evaluations, 30) << "a zero time budget stops after the first batch";
}

INSTANTIATE_TEST_SUITE_P(Stability, OptimizerAtTheExtremes, ::testing::ValuesIn(optimizer_names()),
                         [](const auto& p) {
                           std::string s = p.param;
                           for (char& c : s)
                             if (c == '-') c = '_';
                           return s;
                         });

}  // namespace
}  // namespace lftrack::tracking
