#pragma once
// The real-time loop (DESIGN.md, "One cycle"), one implementation for `lftrack sim`, `run` and
// `replay`: at a fixed period on absolute CLOCK_MONOTONIC deadlines, each cycle runs the stages
//   operator -> acquire (pair, read-back) -> preprocess -> register (warm, time-boxed) ->
//   judge (the verdict on the registration) -> control (prediction, correction) ->
//   gate (the decision) -> actuate (an APPLY sent) ->
//   advance (the state machine's one event) -> settle (hold, beam permit) -> record (journal,
//   statistics)
// in that order, each a function on the cycle's preallocated state (src/loop_impl.hpp,
// src/cycle_stages.cpp, src/cycle_registration.cpp, src/cycle_verdict.cpp, src/cycle_record.cpp).
// The first cycle is ALIGN: the cold, wide-range registration whose result is the set-up move
// (operator-approved: no step limit) and the reference similarity the gate compares against.
// ALIGN becomes TRACK only when the actuator has accepted the set-up move; a refused one is an
// alignment that failed (HOLD), and the operator's resume aligns again.
//
// Control: the registered pose, minus the couch's read-back travel, is the patient's own offset;
// a line through the last few offsets predicts it one latency ahead (motion_predictor.hpp); the
// couch target that cancels the prediction, less the last commanded target, is this cycle's
// correction, which only an APPLY of the gate sends. HOLD and FAULT hold the actuator and drop
// the beam; leaving HOLD is an operator resume, whose first move is approved like the set-up move.
// Without an actuator (replay; track and report) an applied correction is only reported, and
// becomes the reference the next cycle's step is measured from.
//
// Everything is allocated by create(); steady-state cycles allocate nothing (tested), take no
// lock another thread holds for long, and wait only with a deadline. Overruns are counted and
// the missed periods skipped. With `simulated_clock` the loop does not sleep: cycle k starts at
// k periods on a virtual clock on which the cycle's work takes no time (tests, studies; a sim
// run's results are then independent of the host's speed and load, bit for bit from its seed).
// Everything that differs between the two clocks is asked of the run's CycleClock
// (cycle_clock.hpp); no stage branches on the choice.

#include <atomic>
#include <memory>

#include "lftrack/loop/loop_parts.hpp"
#include "lftrack/loop/loop_summary.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::loop {

class TrackingLoop {
 public:
  ~TrackingLoop();
  // Checks the parts against the scene, prepares the plans, opens the frame source and sizes
  // every buffer the cycles use.
  static Result<std::unique_ptr<TrackingLoop>> create(const LoopParts& parts, const LoopSettings& settings);
  // Runs until the cycle count, an operator quit or stop, or request_stop(). Holds the actuator
  // and drops the beam permit on the way out. If anything in a cycle throws (bad_alloc
  // included), the actuator is held and the beam permit dropped before the exception propagates.
  Result<LoopSummary> run();
  // From a signal handler or another thread: the loop ends after the current cycle.
  void request_stop() { stop_.store(true, std::memory_order_relaxed); }

 private:
  struct Impl;
  Result<LoopSummary> run_cycles();
  explicit TrackingLoop(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
  std::atomic<bool> stop_{false};
};

}  // namespace lftrack::loop
