// The surrogate-to-target correlation model (issue 58): what it recovers from exact relations,
// when it may be used, what a changed relation does to its checks, the rate from a noisy stream,
// and that the loop's calls allocate nothing.
#include "lftrack/loop/correlation_model.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "lftrack/loop/allocation_counter.hpp"

namespace lftrack::loop {
namespace {

constexpr double kPeriodS = 4.0;
constexpr std::int64_t kNsPerS = 1'000'000'000;

// Breathing's phase curve (0 at exhale, 1 at inhale) and its rate.
double breath(double t_s) {
  const double s = std::sin(std::numbers::pi * t_s / kPeriodS);
  return s * s;
}
double breath_rate(double t_s) {
  const double w = std::numbers::pi / kPeriodS;
  return w * std::sin(2 * w * t_s);
}

SurrogateSample chest_at(double t_s, double lead_s = 0) {
  return {std::int64_t(t_s * kNsPerS), 10 * breath(t_s + lead_s), 10 * breath_rate(t_s + lead_s)};
}

// The target 8 mm superior-inferior, 2 mm anterior-posterior over a breath.
Eigen::Vector3d target_at(double t_s) {
  return Eigen::Vector3d(0.5, -2.0, 8.0) * breath(t_s);
}

CorrelationModelSpec spec_of(CorrelationModelSpec::Order order, bool hysteresis) {
  CorrelationModelSpec s;
  s.order = order;
  s.hysteresis = hysteresis;
  return s;
}

// The surrogate's readings at 30 Hz over [from_s, to_s), as the loop shows them to the model.
void observe(CorrelationModel* model, double from_s, double to_s, double lead_s) {
  for (double t = from_s; t < to_s; t += 1.0 / 30) model->observe(chest_at(t, lead_s));
}

// Pairs at 1 Hz (off the breath's period, so the phases spread) from t = 0.3 s, with the
// surrogate's readings between them.
void feed(CorrelationModel* model, int pairs, double lead_s) {
  for (int i = 0; i < pairs; ++i) {
    const double t = 0.3 + 1.07 * i;
    observe(model, t - 1.07, t, lead_s);
    model->add(chest_at(t, lead_s), target_at(t));
  }
}

// The largest 3D error of the model's prediction over two breaths sampled at 30 Hz.
double worst_error_mm(const CorrelationModel& model, double lead_s, double from_s) {
  double worst = 0;
  for (double t = from_s; t < from_s + 2 * kPeriodS; t += 1.0 / 30)
    worst = std::max(worst, (model.predict(chest_at(t, lead_s)) - target_at(t)).norm());
  return worst;
}

TEST(CorrelationModel, ALinearRelationIsRecoveredExactly) {
  CorrelationModel model(spec_of(CorrelationModelSpec::Order::kLinear, false));
  feed(&model, 12, 0.0);
  ASSERT_TRUE(model.ready()) << model.not_ready_reason();
  EXPECT_LT(worst_error_mm(model, 0.0, 20), 1e-9);
  EXPECT_LT(model.fit_rms_mm().maxCoeff(), 1e-9);
}

TEST(CorrelationModel, ACurvedRelationNeedsTheQuadraticTerm) {
  // The target follows the chest along a curve: p = 8 b^1.5 superior.
  const auto curved = [](double t) { return Eigen::Vector3d(0, 0, 8 * std::pow(breath(t), 1.5)); };
  CorrelationModel linear(spec_of(CorrelationModelSpec::Order::kLinear, false));
  CorrelationModel quadratic(spec_of(CorrelationModelSpec::Order::kQuadratic, false));
  for (int i = 0; i < 16; ++i) {
    const double t = 0.3 + 1.07 * i;
    observe(&linear, t - 1.07, t, 0);
    observe(&quadratic, t - 1.07, t, 0);
    linear.add(chest_at(t), curved(t));
    quadratic.add(chest_at(t), curved(t));
  }
  ASSERT_TRUE(linear.ready() && quadratic.ready());
  double worst_linear = 0, worst_quadratic = 0;
  for (double t = 20; t < 28; t += 1.0 / 30) {
    worst_linear = std::max(worst_linear, (linear.predict(chest_at(t)) - curved(t)).norm());
    worst_quadratic = std::max(worst_quadratic, (quadratic.predict(chest_at(t)) - curved(t)).norm());
  }
  EXPECT_GT(worst_linear, 0.4);
  EXPECT_LT(worst_quadratic, 0.25 * worst_linear);
}

TEST(CorrelationModel, TheRateTermFollowsAChestThatLeadsTheTarget) {
  // The chest 0.3 s ahead: inhale and exhale take different paths through (s, p).
  CorrelationModel without(spec_of(CorrelationModelSpec::Order::kQuadratic, false));
  CorrelationModel with(spec_of(CorrelationModelSpec::Order::kQuadratic, true));
  feed(&without, 16, 0.3);
  feed(&with, 16, 0.3);
  ASSERT_TRUE(without.ready() && with.ready());
  const double error_without = worst_error_mm(without, 0.3, 20), error_with = worst_error_mm(with, 0.3, 20);
  EXPECT_GT(error_without, 1.0) << "a lead of 0.3 s in a 4 s breath moves an 8 mm target by up to 1.9 mm";
  EXPECT_LT(error_with, 0.5 * error_without) << error_with << " against " << error_without;
}

TEST(CorrelationModel, ItIsNotUsedBeforeItHasSeenABreath) {
  CorrelationModel model(spec_of(CorrelationModelSpec::Order::kQuadratic, true));
  EXPECT_FALSE(model.ready());
  EXPECT_TRUE(std::isnan(model.predict(chest_at(1)).x())) << "no model: nothing the gate could take";
  // Eight pairs within 2 s: enough pairs, not a breathing cycle.
  observe(&model, 0, 2, 0);
  for (int i = 0; i < 8; ++i) model.add(chest_at(0.25 * i), target_at(0.25 * i));
  EXPECT_FALSE(model.ready());
  EXPECT_NE(std::string(model.not_ready_reason()).find("breathing cycle"), std::string::npos)
      << model.not_ready_reason();
  // Pairs over 16 s, but all on the exhale: the surrogate's rate never changes sign.
  CorrelationModel exhale_only(spec_of(CorrelationModelSpec::Order::kLinear, false));
  for (int i = 0; i < 10; ++i) {
    const double t = 2.1 + 4.0 * (i / 2) + 0.3 * (i % 2);  // 2.1-2.4 s into each breath: exhaling
    observe(&exhale_only, t - 2, t, 0);
    exhale_only.add(chest_at(t), target_at(t));
  }
  EXPECT_FALSE(exhale_only.ready());
  EXPECT_NE(std::string(exhale_only.not_ready_reason()).find("inhale"), std::string::npos);
  // A surrogate that never moved fits nothing.
  CorrelationModel frozen(spec_of(CorrelationModelSpec::Order::kLinear, false));
  for (int i = 0; i < 10; ++i) frozen.observe({std::int64_t(i) * kNsPerS, 3.0, 0.0});
  for (int i = 0; i < 10; ++i)
    frozen.add({std::int64_t(i) * kNsPerS, 3.0, i % 2 ? 1e-3 : -1e-3}, target_at(i));
  EXPECT_FALSE(frozen.ready());
  EXPECT_NE(std::string(frozen.not_ready_reason()).find("did not move"), std::string::npos)
      << frozen.not_ready_reason();
}

TEST(CorrelationModel, XraysAtTheSamePhasesOfEveryBreathMakeNoModel) {
  // X-rays every 2 s in a 4 s breath: the surrogate reads the same at every one of them, inhaling
  // and exhaling in turn. A model fitted there would agree with every later X-ray.
  CorrelationModel model(spec_of(CorrelationModelSpec::Order::kQuadratic, true));
  for (int i = 0; i < 20; ++i) {
    const double t = 1.3 + 2.0 * i;  // two heights: 0.73 and 0.29 of the breath
    observe(&model, t - 2, t, 0);
    model.add(chest_at(t), target_at(t) + Eigen::Vector3d(0.01 * (i % 3), 0, 0));  // a registration's scatter
  }
  EXPECT_FALSE(model.ready());
  EXPECT_NE(std::string(model.not_ready_reason()).find("same phases"), std::string::npos)
      << model.not_ready_reason();
  // Without the surrogate's readings there is no range to judge coverage by: no model either.
  CorrelationModel blind(spec_of(CorrelationModelSpec::Order::kLinear, false));
  for (int i = 0; i < 12; ++i) blind.add(chest_at(0.3 + 1.07 * i), target_at(0.3 + 1.07 * i));
  EXPECT_FALSE(blind.ready());
}

TEST(CorrelationModel, TwoPhasesOfEveryBreathMakeNoModelAtAnyPhaseOffset) {
  // X-rays every 2 s of a 4 s breath, at several offsets into the breath and leads of the chest:
  // inhale and exhale at the same heights, two levels only. At no offset may that be a model.
  for (const double lead : {0.0, 0.2, 0.5}) {
    for (const double offset : {0.1, 0.3, 0.5, 0.7, 1.0}) {
      SCOPED_TRACE(testing::Message() << "lead " << lead << " s, offset " << offset << " s");
      for (const auto order :
           {CorrelationModelSpec::Order::kLinear, CorrelationModelSpec::Order::kQuadratic}) {
        CorrelationModel model(spec_of(order, true));
        for (int i = 0; i < 20; ++i) {
          const double t = offset + 2.0 * i;
          observe(&model, t - 2, t, lead);
          model.add(chest_at(t, lead), target_at(t));
        }
        EXPECT_FALSE(model.ready()) << "fit rms " << model.fit_rms_mm().transpose();
      }
    }
  }
}

TEST(CorrelationModel, AReadingBeyondTheFittedBreathsIsNotWithinTheFit) {
  CorrelationModel model(spec_of(CorrelationModelSpec::Order::kQuadratic, true));
  feed(&model, 12, 0.0);
  ASSERT_TRUE(model.ready());
  EXPECT_TRUE(model.within_fit(chest_at(20.0)));
  EXPECT_TRUE(model.within_fit(chest_at(22.0)));
  SurrogateSample cough = chest_at(22.0);
  cough.amplitude *= 1.5;  // a breath half again as deep
  EXPECT_FALSE(model.within_fit(cough));
  SurrogateSample gasp = chest_at(22.0);
  gasp.rate_per_s = 3 * 10 * std::numbers::pi / kPeriodS;  // three times the breath's fastest
  EXPECT_FALSE(model.within_fit(gasp)) << "the rate term extrapolates as freely as the amplitude's";
  EXPECT_FALSE(model.within_fit({0, std::nan(""), 0}));
}

TEST(CorrelationModel, ARelationThatChangesIsRefittedOnceThenHeld) {
  CorrelationModelSpec spec = spec_of(CorrelationModelSpec::Order::kQuadratic, true);
  spec.tolerance_mm = 1.0;
  CorrelationModel model(spec);
  feed(&model, 12, 0.0);
  ASSERT_TRUE(model.ready());
  double t = 0.3 + 1.07 * 12;
  observe(&model, t - 1.07, t + 3, 0);
  EXPECT_EQ(model.check(chest_at(t), target_at(t)), CorrelationModel::Check::kAgrees);
  EXPECT_LT(model.last_check_error_mm(), 1e-6);
  // The target moves 3 mm inferior under the same chest (the patient slid on the couch).
  const Eigen::Vector3d slid(0, 0, -3);
  t += 1.07;
  EXPECT_EQ(model.check(chest_at(t), target_at(t) + slid), CorrelationModel::Check::kMissRefitted);
  EXPECT_GT(model.last_check_error_mm(), 2.0);
  t += 1.07;
  EXPECT_EQ(model.check(chest_at(t), target_at(t) + slid), CorrelationModel::Check::kMissAgain)
      << "a second miss in a row: the loop holds";
  model.reset();
  EXPECT_FALSE(model.ready());
  EXPECT_EQ(model.pairs(), 0);
}

TEST(CorrelationModel, AnAbsurdPairChangesNothingAndIsNeverTrusted) {
  CorrelationModel model(spec_of(CorrelationModelSpec::Order::kLinear, false));
  feed(&model, 10, 0.0);
  ASSERT_TRUE(model.ready());
  const int pairs = model.pairs();
  const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(model.add({0, nan, 0}, target_at(0)));
  EXPECT_FALSE(model.add(chest_at(30), Eigen::Vector3d(inf, 0, 0)));
  EXPECT_EQ(model.pairs(), pairs);
  EXPECT_EQ(model.check({0, 1e308 * 10, 0}, target_at(0)), CorrelationModel::Check::kMissAgain);
  EXPECT_TRUE(model.ready());
  EXPECT_TRUE(model.predict(chest_at(31)).allFinite());
  EXPECT_TRUE(std::isnan(model.predict({0, nan, 0}).x()));
}

TEST(CorrelationModel, SpecsOutsideTheirRangesAreRefused) {
  EXPECT_TRUE(check_correlation_model_spec({}).ok());
  const auto refused = [](auto change) {
    CorrelationModelSpec s;
    change(s);
    return !check_correlation_model_spec(s).ok();
  };
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) { s.window = 3; }));
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) { s.window = CorrelationModel::kCapacity + 1; }));
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) { s.min_pairs = 4; }));  // a line and the rate: 3 terms + 2
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) {
    s.order = CorrelationModelSpec::Order::kQuadratic;
    s.min_pairs = 5;  // a parabola and the rate: 4 terms + 2
  }));
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) { s.min_pairs = 30; }));  // beyond the window
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) { s.min_span_s = -1; }));
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) { s.min_span_s = 0; }));  // no breath: no coverage rule
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) { s.min_span_s = std::nan(""); }));
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) { s.tolerance_mm = 0; }));
  EXPECT_TRUE(refused([](CorrelationModelSpec& s) { s.tolerance_mm = 1e12; }));
}

TEST(SurrogateStream, TheRateOfANoisyStreamIsItsSlopeNotItsDifferences) {
  std::mt19937_64 random(3);
  std::normal_distribution<double> noise(0.0, 0.1);  // mm, an optical tracker's
  SurrogateStream stream(0.1);
  double worst_rate_error = 0;
  for (int i = 0; i < 600; ++i) {  // 10 s at 60 Hz
    const double t = i / 60.0;
    ASSERT_TRUE(stream.push(std::int64_t(t * kNsPerS), 10 * breath(t) + noise(random)));
    SurrogateSample s;
    if (i >= 6) {
      ASSERT_TRUE(stream.newest(&s));
      // The slope over the readings of the last 0.1 s lags the true rate by about 0.05 s; compare
      // with the rate there.
      worst_rate_error = std::max(worst_rate_error, std::abs(s.rate_per_s - 10 * breath_rate(t - 0.05)));
    }
  }
  // Differences of readings 1/60 s apart would err by 0.1 * sqrt(2) * 60 = 8.5 mm/s at one sd.
  EXPECT_LT(worst_rate_error, 6.0);
  EXPECT_FALSE(stream.push(0, 1.0)) << "a reading older than the newest";
  EXPECT_FALSE(stream.push(std::int64_t(11) * kNsPerS, std::nan("")));
}

TEST(CorrelationModel, TheLoopsCallsAllocateNothing) {
  CorrelationModel model(spec_of(CorrelationModelSpec::Order::kQuadratic, true));
  SurrogateStream stream;
  const std::uint64_t before = process_allocation_count();
  for (int i = 0; i < 200; ++i) {
    const double t = 0.3 + 1.07 * i;
    stream.push(std::int64_t(t * kNsPerS), 10 * breath(t));
    observe(&model, t - 1.07, t, 0);
    (void)model.check(chest_at(t), target_at(t));
    (void)model.predict(chest_at(t + 0.5));
    SurrogateSample newest;
    (void)stream.newest(&newest);
    (void)model.within_fit(newest);
  }
  EXPECT_EQ(process_allocation_count() - before, 0u);
  EXPECT_TRUE(model.ready());
  EXPECT_EQ(model.pairs(), CorrelationModelSpec{}.window);
}

}  // namespace
}  // namespace lftrack::loop
