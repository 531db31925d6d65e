#pragma once
// What a TrackingLoop run reports: counts per state and gate decision, the transitions, timing
// and (simulation) residual statistics, allocations per cycle.

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "lftrack/loop/tracking_states.hpp"

namespace lftrack::host {

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
  double readback_p50_ms = 0, readback_p99_ms = 0;  // the actuator's read-back: a protocol's round trip
  double evaluations_mean = 0;
  std::optional<double> allocations_per_cycle;
  std::int64_t allocation_cycles = 0;  // the steady-state cycles they were counted over
  std::vector<LoopTransition> transitions;
  std::string ended;          // why the loop stopped
  std::string journal_error;  // set by LoopSession::run when the journal could not be written
};
nlohmann::json to_json(const LoopSummary& summary);

}  // namespace lftrack::host
