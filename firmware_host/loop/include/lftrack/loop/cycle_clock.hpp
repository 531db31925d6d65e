#pragma once
// The loop's time. A run keeps one of two clocks (LoopSettings::simulated_clock chooses), and
// every place where a cycle's behaviour depends on whose time it keeps asks this interface, so
// the stages themselves have no branch on the clock:
//
// - The host's clock (CLOCK_MONOTONIC): cycles start on period boundaries and the loop sleeps
//   between them; a cycle that overruns skips the periods it ran into (cycle_schedule.hpp); a
//   stage's wall time is boxed by its budget; the command latency is measured link by link.
// - The simulated clock: cycle k starts at the loop's start plus k periods whatever the host took,
//   and the cycle's decisions see its start as now: a frame arrives at its exposure, a command is
//   acknowledged at its deadline, and no stage budget cuts a stage short. A run then repeats bit
//   for bit from its seed under any load (counting the host's computing time made a loaded run's
//   frames "stale" where an idle one's were not, and two runs of one seed diverged).

#include <cstdint>
#include <memory>

#include "lftrack/loop/cycle_schedule.hpp"

namespace lftrack::loop {

class CycleObserver;

// A stage budget that never runs out (ms).
inline constexpr double kUnlimitedStageMs = 1e12;

class CycleClock {
 public:
  virtual ~CycleClock() = default;

  // Now, as the decisions of the cycle that started at cycle_start_ns see it (a frame's age, the
  // surrogate's readings).
  virtual std::int64_t now_ns(std::int64_t cycle_start_ns) const = 0;
  // The deadline of a command sent in the cycle that started at cycle_start_ns: the period's end.
  // The alignment's set-up move goes out after a cold registration that may have run past the
  // period (ALIGN is not an overrun), so on the host's clock it gets one period from now.
  virtual std::int64_t command_due_ns(std::int64_t cycle_start_ns, std::int64_t period_ns,
                                      bool aligning) const = 0;
  // When a command the actuator accepted, due at due_ns, counts as acknowledged.
  virtual std::int64_t acknowledged_ns(std::int64_t due_ns) const = 0;
  // The wall time a stage may take, given what its budget leaves it (ms): that, or
  // kUnlimitedStageMs where the host's time is not the loop's.
  virtual double stage_budget_ms(double budget_ms) const = 0;
  // Where the cycle's own work starts, for its statistics: when the cycle began, or when its
  // frames arrived (in a cycle without a pair, its read-back ended) where producing them (the
  // simulator's renderer) is not the loop's time.
  virtual std::int64_t work_started_ns(std::int64_t cycle_wall_start_ns,
                                       std::int64_t frames_arrived_ns) const = 0;
  // Whether a cycle's stage times are the host's, so that the latency chain measures something.
  virtual bool measures_latency() const = 0;
  // Whether cycles follow one another with no idle time between them, in which the journal's and
  // the archive's writers would catch up: the loop then waits for them before a cycle.
  virtual bool back_to_back() const = 0;
  // The cycle after cycle `index` of a loop that started at loop_start_ns; the cycle started at
  // start_ns and its work ended at wall_end_ns.
  virtual NextCycle next(std::int64_t loop_start_ns, std::int64_t period_ns, std::int64_t index,
                         std::int64_t start_ns, std::int64_t wall_end_ns) const = 0;
  // Waits for the next cycle's start (the host's clock), or not at all.
  virtual void wait_until(std::int64_t start_ns) const = 0;
};

// The host's clock.
std::unique_ptr<CycleClock> host_cycle_clock();
// The simulated clock. `observer` (may be null; must outlive the clock) may inject host stalls
// (CycleObserver::simulated_stall_ns): the cycle is then taken to have lasted its period and the
// stall, and overruns and skips periods exactly as on the host's clock.
std::unique_ptr<CycleClock> simulated_cycle_clock(CycleObserver* observer);

}  // namespace lftrack::loop
