// Imaging on demand (imaging_on_demand.hpp): when a cycle takes a pair, the surrogate's watch, and
// the gate's answers to a model cycle, a failed surrogate and a model that missed twice.

#include "lftrack/loop/imaging_on_demand.hpp"

#include <gtest/gtest.h>

#include <limits>

#include "lftrack/loop/safety_gate.hpp"

namespace lftrack::loop {
namespace {

constexpr std::int64_t kMs = 1'000'000;
constexpr std::int64_t kPeriod = 100 * kMs;

ImagingSpec model_imaging() {
  ImagingSpec spec;
  spec.mode = ImagingSpec::Mode::kModel;
  spec.xray_hz = 1;
  spec.stale_s = 3;
  return spec;
}

ImagingState ready_state() {
  ImagingState s;
  s.tracking = true;
  s.model_ready = true;
  s.surrogate_within_fit = true;
  s.last_pair_ns = 0;
  s.last_agreed_ns = 0;
  return s;
}

TEST(ImagingOnDemand, EveryCycleImagesEveryCycle) {
  ImagingSpec spec;
  EXPECT_EQ(next_imaging(spec, ready_state(), 300 * kMs, kPeriod), ImagingReason::kEveryCycle);
  ImagingState aligning = ready_state();
  aligning.tracking = false;
  EXPECT_EQ(next_imaging(model_imaging(), aligning, 300 * kMs, kPeriod), ImagingReason::kEveryCycle)
      << "ALIGN and HOLD take a pair every cycle";
}

TEST(ImagingOnDemand, PairsAtTheXrayRateOnceTheModelIsReady) {
  const ImagingSpec spec = model_imaging();
  ImagingState s = ready_state();
  s.model_ready = false;
  EXPECT_EQ(next_imaging(spec, s, 300 * kMs, kPeriod), ImagingReason::kBuildingModel);
  s = ready_state();
  int pairs = 0;
  for (std::int64_t k = 1; k <= 100; ++k) {  // 10 s at 10 Hz
    const ImagingReason r = next_imaging(spec, s, k * kPeriod, kPeriod);
    if (r == ImagingReason::kScheduled) {
      ++pairs;
      s.last_pair_ns = s.last_agreed_ns = k * kPeriod;
    } else {
      EXPECT_EQ(r, ImagingReason::kNone) << k;
    }
  }
  EXPECT_EQ(pairs, 10) << "1 Hz at 10 Hz: every tenth cycle, not every eleventh";
}

TEST(ImagingOnDemand, EarlyPairsForACoughAMissAndAStaleModel) {
  const ImagingSpec spec = model_imaging();
  ImagingState s = ready_state();
  s.surrogate_within_fit = false;
  EXPECT_EQ(next_imaging(spec, s, 300 * kMs, kPeriod), ImagingReason::kOutsideFit);
  s = ready_state();
  s.miss_pending = true;
  EXPECT_EQ(next_imaging(spec, s, 300 * kMs, kPeriod), ImagingReason::kConfirmMiss);
  s = ready_state();
  s.last_pair_ns = 3000 * kMs;  // a pair that did not agree (a registration that failed) ...
  s.last_agreed_ns = 0;         // ... 3 s after the last agreement
  EXPECT_EQ(next_imaging(spec, s, 3200 * kMs, kPeriod), ImagingReason::kModelStale);
}

TEST(SurrogateMonitor, StoppedFrozenJumpedAndNotFinite) {
  SurrogateLimits limits;  // stale 100 ms, jump 5, freeze 0.5 s
  SurrogateMonitor m(limits);
  EXPECT_EQ(m.fault_at(0), SurrogateFault::kNoReadings);
  double s = 0;
  std::int64_t t = 0;
  for (int i = 0; i < 60; ++i, t += 16 * kMs) m.on_reading(t, s += 0.05);
  EXPECT_EQ(m.fault_at(t), SurrogateFault::kOk);
  EXPECT_EQ(m.fault_at(t - 16 * kMs + 100 * kMs), SurrogateFault::kOk);
  EXPECT_EQ(m.fault_at(t - 16 * kMs + 101 * kMs), SurrogateFault::kStale);
  // Frozen: the same value for 0.5 s.
  for (int i = 0; i < 40; ++i, t += 16 * kMs) m.on_reading(t, s);
  EXPECT_EQ(m.fault_at(t), SurrogateFault::kFrozen);
  m.on_reading(t, s + 0.01);
  EXPECT_EQ(m.fault_at(t), SurrogateFault::kOk) << "moving again";
  // A jump stays until reset.
  t += 16 * kMs;
  m.on_reading(t, s + 6);
  for (int i = 0; i < 10; ++i) m.on_reading(t += 16 * kMs, s + 6 + 0.01 * i);
  EXPECT_EQ(m.fault_at(t), SurrogateFault::kJump);
  m.reset();
  EXPECT_EQ(m.fault_at(t), SurrogateFault::kOk) << "a resume clears the jump and keeps the newest reading";
  // Across a gap (a long cycle that dropped readings) a breath's change is no jump.
  t += 2000 * kMs;
  m.on_reading(t, s - 3);
  EXPECT_EQ(m.fault_at(t), SurrogateFault::kOk);
  m.on_reading(t, std::numeric_limits<double>::quiet_NaN());
  EXPECT_EQ(m.fault_at(t), SurrogateFault::kNotFinite);
  m.on_reading(t + 16 * kMs, 1.0);
  EXPECT_EQ(m.fault_at(t + 16 * kMs), SurrogateFault::kOk);
  // A reading not newer than the last is ignored (the stream refuses it too).
  m.on_reading(t, 100.0);
  EXPECT_EQ(m.fault_at(t + 16 * kMs), SurrogateFault::kOk);
  for (int r = 0; r <= int(SurrogateFault::kNotFinite); ++r)
    EXPECT_STRNE(to_string(static_cast<SurrogateFault>(r)), "?");
  for (int r = 0; r <= int(ImagingReason::kBuildingModel); ++r)
    EXPECT_STRNE(to_string(static_cast<ImagingReason>(r)), "?");
}

GateInput model_cycle_input() {
  GateInput in;
  in.model_cycle = true;
  in.views = 0;
  in.registration_ok = true;
  in.step << 0.3, 0.2, 0.5, 0, 0, 0;
  in.total << 1, 1, 3, 0, 0, 0;
  in.frame_age_ms = 5;
  return in;
}

TEST(ImagingOnDemand, TheGateAppliesAModelCycleAndHoldsOnTheSurrogateOrTwoMisses) {
  const SafetyLimits limits;
  EXPECT_EQ(evaluate_gate(limits, model_cycle_input()).decision, GateDecision::kApply)
      << "no frames and no similarities are judged in a model cycle";
  GateInput in = model_cycle_input();
  in.registration_ok = false;  // the model cannot say here
  in.consecutive_failures = 2;
  GateOutput out = evaluate_gate(limits, in);
  EXPECT_EQ(out.decision, GateDecision::kSkip);
  EXPECT_EQ(out.reason, GateReason::kModelNotReady);
  EXPECT_EQ(out.consecutive_failures, 2) << "not counted: a pair follows";
  in = model_cycle_input();
  const std::pair<SurrogateFault, GateReason> faults[] = {
      {SurrogateFault::kNoReadings, GateReason::kSurrogateStopped},
      {SurrogateFault::kStale, GateReason::kSurrogateStopped},
      {SurrogateFault::kJump, GateReason::kSurrogateJumped},
      {SurrogateFault::kFrozen, GateReason::kSurrogateFrozen},
      {SurrogateFault::kNotFinite, GateReason::kSurrogateNotFinite}};
  for (const auto& [fault, reason] : faults) {
    in.surrogate_fault = fault;
    out = evaluate_gate(limits, in);
    EXPECT_EQ(out.decision, GateDecision::kHold);
    EXPECT_EQ(out.reason, reason);
  }
  in = model_cycle_input();
  in.model_missed = true;
  out = evaluate_gate(limits, in);
  EXPECT_EQ(out.decision, GateDecision::kHold);
  EXPECT_EQ(out.reason, GateReason::kModelMissed);
  in = model_cycle_input();
  in.step(2) = 2.5;  // the model's correction too is limited
  EXPECT_EQ(evaluate_gate(limits, in).reason, GateReason::kStepTooLarge);
  in = model_cycle_input();
  in.offset_from_plan(2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(evaluate_gate(limits, in).reason, GateReason::kNonFinite);
  in = model_cycle_input();
  in.frame_age_ms = 200;  // the surrogate's reading is stale
  EXPECT_EQ(evaluate_gate(limits, in).reason, GateReason::kStaleFrame);
}

}  // namespace
}  // namespace lftrack::loop
