#pragma once
// The real-time loop (DESIGN.md, "One cycle"), one implementation for `lftrack sim`, `run` and
// `replay`: at a fixed period on absolute CLOCK_MONOTONIC deadlines, each cycle
//   acquire pair -> preprocess -> register (warm, time-boxed) -> safety gate -> actuate -> journal.
// The first cycle is ALIGN: the cold, wide-range registration whose result is the set-up move
// (operator-approved: no step limit) and the reference similarity the gate compares against.
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
// k periods on a virtual clock (tests, studies; a sim run's results are then independent of the
// host's speed).

#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/host/frame_archive.hpp"
#include "lftrack/host/histogram.hpp"
#include "lftrack/host/journal.hpp"
#include "lftrack/host/motion_predictor.hpp"
#include "lftrack/host/operator_input.hpp"
#include "lftrack/host/registration_verdict.hpp"
#include "lftrack/host/safety_gate.hpp"
#include "lftrack/host/scene.hpp"
#include "lftrack/host/tracking_states.hpp"
#include "lftrack/sim/simulated_room.hpp"
#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/frame_quality.hpp"
#include "lftrack/tracking/registration.hpp"

namespace lftrack::host {

// What the loop runs on. Owned by the caller; all must outlive the loop. Optional parts may be
// null: no actuator (track and report), no journal or archive, no operator, no truth (not a simulation),
// no allocation counter (allocations_per_cycle is then not reported).
struct LoopParts {
  const PreparedScene* scene = nullptr;
  tracking::Registration* registration = nullptr;
  drivers::FrameSource* frames = nullptr;
  std::vector<tracking::DetectorCorrection> corrections;  // per detector
  drivers::Actuator* actuator = nullptr;
  JournalWriter* journal = nullptr;
  FrameArchive* archive = nullptr;  // every acquired pair, numbered by cycle
  OperatorInput* operator_input = nullptr;
  const sim::SimulatedRoom* truth = nullptr;
  // Renders the DRR at the alignment's result for the verdict's NCC check (the registration's
  // renderer); null: the check is not made.
  const tracking::DrrRenderer* check_renderer = nullptr;
  std::uint64_t (*allocation_count)() = nullptr;
};

struct LoopSettings {
  LoopSpec loop;  // period, budgets, plans, prediction
  SafetyLimits limits;
  double actuator_latency_s = 0;  // for the default look-ahead
  std::int64_t cycles = 0;        // cycles to run (0: until quit or stop)
  bool simulated_clock = false;
  bool status_line = false;                    // one line per cycle on stderr (a terminal)
  bool announce_holds = false;                 // without a status line: a line on stderr per HOLD/FAULT
  int warmup_cycles = 5;                       // after ALIGN, before allocations are counted
  tracking::FrameQualityLimits image_quality;  // the image-quality gate's limits
  // The alignment's result is judged as `lftrack register` judges it (registration_verdict.hpp:
  // the measure's expected similarity, NCC against the DRR, per-view agreement, the pose
  // envelope); a rejected alignment is no result, with the verdict's reason: HOLD, nothing
  // moves. Unset: not judged.
  std::optional<VerdictLimits> verdict;
};

struct LoopTransition {
  std::int64_t cycle = 0;
  TrackingState from = TrackingState::kIdle, to = TrackingState::kIdle;
  const char* reason = "";
};

struct LoopSummary {
  std::int64_t cycles = 0;  // executed
  std::int64_t overruns = 0;
  std::int64_t skipped_periods = 0;
  std::int64_t holds = 0;                   // entries into HOLD
  std::int64_t faults = 0;                  // entries into FAULT
  std::int64_t commands = 0;                // corrections sent
  std::int64_t operator_refused = 0;        // operator commands refused or discarded (journal: per cycle)
  std::array<std::int64_t, 5> states{};     // cycles ending in each TrackingState
  std::array<std::int64_t, 4> decisions{};  // per GateDecision
  bool aligned = false;
  double align_ms = 0;
  // Residual of the true patient offset after correction (simulation only), TRACK cycles.
  std::optional<double> residual_mean_mm, residual_p95_mm, residual_max_mm;
  double cycle_p50_ms = 0, cycle_p95_ms = 0, cycle_p99_ms = 0, cycle_max_ms = 0;  // work, not sleep
  double registration_p50_ms = 0, registration_p95_ms = 0, registration_max_ms = 0;
  // Waiting for the pair (real clock: from the cycle's start; simulated: the copy only), and
  // preprocessing it; TRACK/HOLD cycles.
  double acquire_p95_ms = 0, acquire_max_ms = 0, preprocess_p95_ms = 0, preprocess_max_ms = 0;
  double evaluations_mean = 0;
  std::optional<double> allocations_per_cycle;
  std::int64_t allocation_cycles = 0;  // the steady-state cycles they were counted over
  std::vector<LoopTransition> transitions;
  std::string ended;          // why the loop stopped
  std::string journal_error;  // set by LoopSession::run when the journal could not be written
};
nlohmann::json to_json(const LoopSummary& summary);

class TrackingLoop {
 public:
  ~TrackingLoop();
  // Checks the parts against the scene, prepares the plans, opens the frame source and sizes
  // every buffer the cycles use.
  static Result<std::unique_ptr<TrackingLoop>> create(const LoopParts& parts, const LoopSettings& settings);
  // Runs until the cycle count, an operator quit or stop, or request_stop(). Holds the actuator
  // on the way out.
  Result<LoopSummary> run();
  // From a signal handler or another thread: the loop ends after the current cycle.
  void request_stop() { stop_.store(true, std::memory_order_relaxed); }

 private:
  struct Impl;
  explicit TrackingLoop(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
  std::atomic<bool> stop_{false};
};

}  // namespace lftrack::host
