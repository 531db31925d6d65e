// The host's and the simulated clock (cycle_clock.hpp).

#include "lftrack/loop/cycle_clock.hpp"

#include <algorithm>

#include "lftrack/loop/loop_parts.hpp"

namespace lftrack::loop {

namespace {

class HostCycleClock final : public CycleClock {
 public:
  std::int64_t now_ns(std::int64_t) const override { return monotonic_now_ns(); }
  std::int64_t command_due_ns(std::int64_t cycle_start_ns, std::int64_t period_ns,
                              bool aligning) const override {
    return aligning ? std::max(cycle_start_ns, monotonic_now_ns()) + period_ns : cycle_start_ns + period_ns;
  }
  std::int64_t acknowledged_ns(std::int64_t) const override { return monotonic_now_ns(); }
  double stage_budget_ms(double budget_ms) const override { return budget_ms; }
  std::int64_t work_started_ns(std::int64_t cycle_wall_start_ns, std::int64_t) const override {
    return cycle_wall_start_ns;
  }
  bool measures_latency() const override { return true; }
  bool back_to_back() const override { return false; }
  NextCycle next(std::int64_t loop_start_ns, std::int64_t period_ns, std::int64_t index, std::int64_t,
                 std::int64_t wall_end_ns) const override {
    return next_cycle(loop_start_ns, period_ns, index, wall_end_ns);
  }
  void wait_until(std::int64_t start_ns) const override { sleep_until_ns(start_ns); }
};

class SimulatedCycleClock final : public CycleClock {
 public:
  explicit SimulatedCycleClock(CycleObserver* observer) : observer_(observer) {}
  std::int64_t now_ns(std::int64_t cycle_start_ns) const override { return cycle_start_ns; }
  std::int64_t command_due_ns(std::int64_t cycle_start_ns, std::int64_t period_ns, bool) const override {
    return cycle_start_ns + period_ns;
  }
  std::int64_t acknowledged_ns(std::int64_t due_ns) const override { return due_ns; }
  double stage_budget_ms(double) const override { return kUnlimitedStageMs; }
  std::int64_t work_started_ns(std::int64_t, std::int64_t frames_arrived_ns) const override {
    return frames_arrived_ns;
  }
  bool measures_latency() const override { return false; }
  bool back_to_back() const override { return true; }
  NextCycle next(std::int64_t loop_start_ns, std::int64_t period_ns, std::int64_t index,
                 std::int64_t start_ns, std::int64_t) const override {
    const std::int64_t stall_ns = observer_ != nullptr ? observer_->simulated_stall_ns(index) : 0;
    if (stall_ns > 0) return next_cycle(loop_start_ns, period_ns, index, start_ns + period_ns + stall_ns);
    NextCycle next;
    next.index = index + 1;
    next.start_ns = loop_start_ns + next.index * period_ns;
    return next;
  }
  void wait_until(std::int64_t) const override {}

 private:
  CycleObserver* observer_;
};

}  // namespace

std::unique_ptr<CycleClock> host_cycle_clock() {
  return std::make_unique<HostCycleClock>();
}

std::unique_ptr<CycleClock> simulated_cycle_clock(CycleObserver* observer) {
  return std::make_unique<SimulatedCycleClock>(observer);
}

}  // namespace lftrack::loop
