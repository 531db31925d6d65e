// Every optimizer, through the factory, on the same problems (DESIGN.md test level 2).

#include "lftrack/tracking/optimizer.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <thread>

namespace lftrack::tracking {
namespace {

// A smooth, coupled, anisotropic bowl with its minimum at `target` (not on any step grid).
class Bowl : public CostFunction {
 public:
  explicit Bowl(Vector6d target) : target_(std::move(target)) {}
  double cost(const Vector6d& x) override {
    ++evaluations;
    const Vector6d d = x - target_;
    double c = 0;
    for (int i = 0; i < 6; ++i) c += (1.0 + 0.5 * i) * d(i) * d(i);
    c += 0.6 * d(0) * d(4) + 0.4 * d(1) * d(5);  // weak couplings within the decoupled pairs
    return 1 - std::exp(-0.02 * c);           // saturates far away, like a similarity
  }
  int evaluations = 0;

 private:
  Vector6d target_;
};

// The offset the bowl's minimum sits at (mm, and rotation-like units), and steps from 2 mm to 0.01.
Vector6d known_offset() {
  Vector6d target;
  target << 3.3, -2.1, 1.7, -2.6, 0.9, 2.2;
  return target;
}
OptimizerSettings two_mm_to_a_hundredth() {
  OptimizerSettings s;
  s.initial_step_mm = 2;
  s.final_step_mm = 0.01;
  return s;
}

// A cold set-up's first pass (the robust plan's): the translations move to their best with the
// rotations held where they started, untouched.
TEST(Optimizer, QuadraticNeighbourWithTranslationsOnlyHoldsTheRotations) {
  Bowl bowl(known_offset());
  OptimizerSettings s = two_mm_to_a_hundredth();
  s.translations_only = true;
  const OptimizerResult r = (*make_optimizer("quadratic-neighbour", s))->minimize(bowl, Vector6d::Zero(), {});
  EXPECT_EQ(r.stop, OptimizerStop::kConverged);
  EXPECT_EQ(r.x.tail<3>().cwiseAbs().maxCoeff(), 0.0) << r.x.transpose();
  // With x(3..5) = 0 the bowl's couplings move the best x(0) and x(1): d0 = -0.3 d4, d1 = -0.4 d5 / 3.
  EXPECT_NEAR(r.x(0), 3.3 + 0.3 * 0.9, 0.05) << r.x.transpose();
  EXPECT_NEAR(r.x(1), -2.1 + 0.4 * 2.2 / 3, 0.05) << r.x.transpose();
  EXPECT_NEAR(r.x(2), 1.7, 0.05) << r.x.transpose();
}

class EveryOptimizer : public ::testing::TestWithParam<std::string> {};

TEST_P(EveryOptimizer, RecoversAKnownOffset) {
  const Vector6d target = known_offset();
  Bowl bowl(target);
  OptimizerSettings s = two_mm_to_a_hundredth();
  s.record_trace = true;
  auto optimizer = make_optimizer(GetParam(), s);
  ASSERT_TRUE(optimizer.ok()) << optimizer.status().message();
  const OptimizerResult r = (*optimizer)->minimize(bowl, Vector6d::Zero(), {});
  EXPECT_LT((r.x - target).cwiseAbs().maxCoeff(), 0.05) << GetParam() << ": " << r.x.transpose();
  EXPECT_EQ(r.evaluations, bowl.evaluations);
  EXPECT_EQ(r.stop, OptimizerStop::kConverged);
  ASSERT_FALSE(r.trace.empty());
  EXPECT_LE(r.trace.back().cost, r.trace.front().cost);
}

TEST_P(EveryOptimizer, WorksInScaledUnits) {
  Vector6d target;
  target << 3, -2, 1, 0.02, -0.01, 0.015;  // mm and radians
  Vector6d scale;
  scale << 1, 1, 1, 0.01, 0.01, 0.01;
  class Scaled : public CostFunction {
   public:
    Scaled(Vector6d t, Vector6d s) : bowl_(t.cwiseQuotient(s)), scale_(std::move(s)) {}
    double cost(const Vector6d& x) override { return bowl_.cost(x.cwiseQuotient(scale_)); }
    Bowl bowl_;
    Vector6d scale_;
  } cost(target, scale);
  OptimizerSettings s;
  s.scale = scale;
  s.final_step_mm = 0.01;
  const OptimizerResult r = make_optimizer(GetParam(), s).value()->minimize(cost, Vector6d::Zero(), {});
  EXPECT_LT((r.x - target).cwiseQuotient(scale).cwiseAbs().maxCoeff(), 0.05) << GetParam();
}

TEST_P(EveryOptimizer, KeepsToItsBudgets) {
  Bowl bowl(Vector6d::Constant(5));
  OptimizerSettings s;
  s.final_step_mm = 1e-6;
  OptimizerBudget budget;
  budget.max_evaluations = 40;
  const OptimizerResult r = make_optimizer(GetParam(), s).value()->minimize(bowl, Vector6d::Zero(), budget);
  EXPECT_LE(r.evaluations, 40);
  EXPECT_EQ(r.stop, OptimizerStop::kEvaluationBudget);
  budget.max_evaluations = 1000000;
  budget.max_ms = 0;
  const OptimizerResult t = make_optimizer(GetParam(), s).value()->minimize(bowl, Vector6d::Zero(), budget);
  EXPECT_EQ(t.stop, OptimizerStop::kTimeBudget);
}

// A bowl whose every evaluation takes exactly 3 ms on a virtual clock (the budget's clock), so
// that what fits a time budget is decided the same way on a loaded machine as on an idle one
// (with a 3 ms sleep on the steady clock, a loaded CI machine once made a 3 ms evaluation look
// slow enough to refuse a batch the test expected to run).
class SlowBowl : public CostFunction, public BudgetClock {
 public:
  double cost(const Vector6d& x) override {
    virtual_ms += ms_per_evaluation;
    return bowl.cost(x);
  }
  double now_ms() const override { return virtual_ms; }
  // The budget, counted on this bowl's clock.
  OptimizerBudget budget(double max_ms) const {
    OptimizerBudget b;
    b.max_ms = max_ms;
    b.clock = this;
    return b;
  }
  Bowl bowl{Vector6d::Constant(5)};
  double ms_per_evaluation = 3;
  double virtual_ms = 1e6;  // any origin: a search counts from its start
};

// A batch that would end past the time budget is not started. Each evaluation takes 3 ms and the
// budget is 60 ms. quadratic-neighbour evaluates its start (3 ms), then its first batch of 12
// neighbours and a jump (42 ms in all); the next batch of 13, at the 3 ms an evaluation it has
// seen, would end at 81 ms, so it stops with 14 evaluations. (It went on to 27 before: 42 ms is
// inside the budget.) A first batch that ran past the budget stops it at 14 too.
TEST(Optimizer, StartsNoBatchThatWouldEndPastTheTimeBudget) {
  SlowBowl slow;
  OptimizerSettings s;
  s.final_step_mm = 1e-3;
  const auto optimizer = make_optimizer("quadratic-neighbour", s).value();
  const OptimizerResult r = optimizer->minimize(slow, Vector6d::Zero(), slow.budget(60));
  EXPECT_EQ(r.evaluations, 14);
  EXPECT_EQ(r.stop, OptimizerStop::kTimeBudget);
  EXPECT_DOUBLE_EQ(r.elapsed_ms, 42);
  EXPECT_DOUBLE_EQ(r.ms_per_evaluation, 3);
  EXPECT_LE(r.elapsed_ms, 60);
  // 80 ms still refuses the batch that would end at 81; 81 ms takes it.
  EXPECT_EQ(optimizer->minimize(slow, Vector6d::Zero(), slow.budget(80)).evaluations, 14);
  EXPECT_EQ(optimizer->minimize(slow, Vector6d::Zero(), slow.budget(81)).evaluations, 27);
  slow.ms_per_evaluation = 10;  // the first batch of 13 alone ends at 140 ms, past the budget
  EXPECT_EQ(optimizer->minimize(slow, Vector6d::Zero(), slow.budget(60)).evaluations, 14);
}

// Until a search has timed a batch after its first, the budget's prior per evaluation judges
// whether the next batch fits. With 3 ms evaluations and a 30 ms budget, the batch of 13 after the
// start would end at 42 ms: without a prior it starts (14 evaluations, reported at 3 ms each);
// with a prior of 3 ms it does not. A prior that is not a positive number is unknown.
TEST(Optimizer, APriorTimePerEvaluationKeepsTheSecondBatchInsideTheBudget) {
  SlowBowl slow;
  OptimizerSettings s;
  s.final_step_mm = 1e-3;
  const auto optimizer = make_optimizer("quadratic-neighbour", s).value();
  OptimizerBudget budget = slow.budget(30);
  const OptimizerResult blind = optimizer->minimize(slow, Vector6d::Zero(), budget);
  EXPECT_EQ(blind.evaluations, 14);
  EXPECT_DOUBLE_EQ(blind.elapsed_ms, 42);  // the overrun a prior prevents
  EXPECT_DOUBLE_EQ(blind.ms_per_evaluation, 3.0);
  for (const double unknown : {0.0, -3.0, std::numeric_limits<double>::quiet_NaN(),
                               std::numeric_limits<double>::infinity()}) {
    budget.prior_ms_per_evaluation = unknown;
    EXPECT_EQ(optimizer->minimize(slow, Vector6d::Zero(), budget).evaluations, 14) << unknown;
  }
  budget.prior_ms_per_evaluation = 3.0;
  const OptimizerResult warned = optimizer->minimize(slow, Vector6d::Zero(), budget);
  EXPECT_EQ(warned.evaluations, 1);
  EXPECT_EQ(warned.stop, OptimizerStop::kTimeBudget);
  EXPECT_EQ(warned.ms_per_evaluation, 0.0);  // no batch after the first ran
  EXPECT_DOUBLE_EQ(warned.first_batch_ms_per_evaluation, 3.0);
  // A stale prior from a slower spell (100 ms) gives way to the first batch's 3 ms (times the
  // ratio, unknown here: 1; 7 or NaN: 1 too): with 80 ms the batch of 13 fits (ending at 42 ms)
  // and runs, so the search measures its time again (the next batch, ending at 81 ms, does not fit).
  budget.max_ms = 80;
  budget.prior_ms_per_evaluation = 100.0;
  for (const double ratio : {0.0, 7.0, std::numeric_limits<double>::quiet_NaN()}) {
    budget.prior_later_to_first_batch = ratio;
    const OptimizerResult recovered = optimizer->minimize(slow, Vector6d::Zero(), budget);
    EXPECT_EQ(recovered.evaluations, 14) << ratio;
    EXPECT_DOUBLE_EQ(recovered.ms_per_evaluation, 3.0) << ratio;
  }
  // A ratio below 1 shrinks the estimate: 3 ms x 0.25 says the batch ends at 12.75 ms, inside a
  // 30 ms budget, so it starts (and, at its real 3 ms an evaluation, runs past it to 42 ms).
  budget.max_ms = 30;
  budget.prior_ms_per_evaluation = 3.0;
  budget.prior_later_to_first_batch = 0.25;
  EXPECT_EQ(optimizer->minimize(slow, Vector6d::Zero(), budget).evaluations, 14);
  budget.max_ms = 12.5;  // 12.75 does not fit 12.5
  EXPECT_EQ(optimizer->minimize(slow, Vector6d::Zero(), budget).evaluations, 1);
}

// The time budget is counted on the steady clock when no clock is given: a search whose
// evaluations sleep cannot take less wall time than they do.
TEST(Optimizer, WithoutAClockTheBudgetIsWallTime) {
  class Sleepy : public CostFunction {
   public:
    double cost(const Vector6d& x) override {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
      return bowl.cost(x);
    }
    Bowl bowl{Vector6d::Constant(5)};
  } sleepy;
  OptimizerSettings s;
  s.final_step_mm = 1e-3;
  OptimizerBudget budget;
  budget.max_ms = 1;  // past after the start point's 2 ms sleep, however fast the machine
  const OptimizerResult r = make_optimizer("quadratic-neighbour", s).value()->minimize(sleepy, Vector6d::Zero(), budget);
  EXPECT_EQ(r.stop, OptimizerStop::kTimeBudget);
  EXPECT_EQ(r.evaluations, 1);
  EXPECT_GE(r.elapsed_ms, 2.0);
  EXPECT_GE(r.first_batch_ms_per_evaluation, 2.0);
}

TEST_P(EveryOptimizer, NonFiniteCostsNeverWin) {
  class Holey : public CostFunction {
   public:
    double cost(const Vector6d& x) override {
      if (x(0) > 0.5) return std::numeric_limits<double>::quiet_NaN();
      return (x - Vector6d::Constant(-1)).squaredNorm();
    }
  } holey;
  OptimizerSettings s;
  s.final_step_mm = 0.01;
  const OptimizerResult r = make_optimizer(GetParam(), s).value()->minimize(holey, Vector6d::Zero(), {});
  EXPECT_TRUE(std::isfinite(r.cost));
  EXPECT_TRUE(r.x.allFinite());
  EXPECT_LT((r.x - Vector6d::Constant(-1)).norm(), 0.1);
  class Nothing : public CostFunction {
   public:
    double cost(const Vector6d&) override { return std::numeric_limits<double>::infinity(); }
  } nothing;
  const OptimizerResult n = make_optimizer(GetParam(), s).value()->minimize(nothing, Vector6d::Zero(), {});
  EXPECT_EQ(n.stop, OptimizerStop::kNonFinite);
  EXPECT_TRUE(n.x.allFinite());
}

INSTANTIATE_TEST_SUITE_P(Optimizer, EveryOptimizer, ::testing::ValuesIn(optimizer_names()),
                         [](const ::testing::TestParamInfo<std::string>& p) {
                           std::string n = p.param;
                           for (char& c : n)
                             if (c == '-') c = '_';
                           return n;
                         });

TEST(Optimizer, RefusesBadSettingsAndNames) {
  OptimizerSettings s;
  s.scale(2) = 0;
  EXPECT_FALSE(make_optimizer("best-neighbour", s).ok());
  s = {};
  s.final_step_mm = 3;
  EXPECT_FALSE(make_optimizer("best-neighbour", s).ok());
  EXPECT_FALSE(make_optimizer("simplex", {}).ok());
  s = {};
  s.translations_only = true;
  EXPECT_TRUE(make_optimizer("quadratic-neighbour", s).ok());
  for (const char* other : {"best-neighbour", "decoupled", "cmaes"}) EXPECT_FALSE(make_optimizer(other, s).ok()) << other;
}

}  // namespace
}  // namespace lftrack::tracking
