#pragma once
// What a TrackingLoop run reports: counts per state and gate decision, the transitions, timing
// and (simulation) residual statistics, allocations per cycle. Plain data: the loop links no JSON
// (its JSON form is lftrack::records').

#include <array>
#include <cstdint>
#include <iterator>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/loop/latency_chain.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/tracking_accuracy.hpp"
#include "lftrack/loop/tracking_states.hpp"

namespace lftrack::loop {

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
  std::array<std::int64_t, kOperatorRefusalCodes> operator_refused_by_reason{};  // index: OperatorRefusal
  std::array<std::int64_t, 5> states{};     // cycles ending in each TrackingState
  std::array<std::int64_t, 4> decisions{};  // per GateDecision
  bool aligned = false;
  double align_ms = 0;
  // Residual of the true patient offset after correction (simulation only), TRACK cycles.
  std::optional<double> residual_mean_mm, residual_p95_mm, residual_max_mm;
  // The target's true offset per room axis and the share of TRACK cycles beyond 1 and 2 mm
  // (simulation only), and exposure-to-acknowledgement latency of the commands sent
  // (tracking_accuracy.hpp).
  std::optional<TargetResidualReport> target_residual;
  std::optional<CommandLatencyReport> command_latency;
  // The same commands' latency link by link (latency_chain.hpp): the real clock only.
  std::optional<LatencyChainReport> latency_chain;
  bool simulated_clock = false;  // then the latency is the modelled one: one command deadline
  double cycle_p50_ms = 0, cycle_p95_ms = 0, cycle_p99_ms = 0, cycle_max_ms = 0;  // work, not sleep
  double registration_p50_ms = 0, registration_p95_ms = 0, registration_max_ms = 0;
  // Waiting for the pair (real clock: from the cycle's start; simulated: the copy only), and
  // preprocessing it; TRACK/HOLD cycles.
  double acquire_p95_ms = 0, acquire_max_ms = 0, preprocess_p95_ms = 0, preprocess_max_ms = 0;
  // The verdict's NCC check in tracking cycles (judge_tracking): how many ran, and their time.
  std::int64_t verdict_checks = 0;
  double verdict_check_p50_ms = 0, verdict_check_p95_ms = 0, verdict_check_max_ms = 0;
  // The verdict's view check (each view registered alone): at alignments and every Nth tracking
  // cycle (view_check_every; -1: no view check); how many ran, refused a result, or were due but
  // did not fit in their cycle (tried again the next), and their time.
  int view_check_every = -1;
  std::int64_t view_checks = 0, view_checks_refused = 0, view_checks_out_of_time = 0;
  double view_check_p50_ms = 0, view_check_max_ms = 0;
  double readback_p50_ms = 0, readback_p99_ms = 0;  // the actuator's read-back: a protocol's round trip
  double evaluations_mean = 0;
  std::optional<double> allocations_per_cycle;
  std::int64_t allocation_cycles = 0;  // the steady-state cycles they were counted over
  // Imaging (imaging_on_demand.hpp): "every_cycle" or "model"; the pairs taken (every cycle that
  // acquired one, ALIGN and HOLD included), the early ones among them, the cycles corrected from the
  // correlation model, its checks (a pair against a ready model) and misses, and their error; the
  // pairs' rate and skin entrance dose over the run's simulated or real time.
  std::string imaging = "every_cycle";
  std::int64_t xray_pairs = 0, early_pairs = 0, model_cycles = 0, model_checks = 0, model_misses = 0;
  double model_check_p50_mm = 0, model_check_p95_mm = 0;
  double pairs_per_minute = 0;
  double dose_per_pair_mGy = 0, dose_mGy_per_minute = 0;  // 0: the dose per pair is not known (or a replay)
  std::string model_not_ready;  // model imaging: why the model was not ready at the end ("" when it was)
  std::vector<LoopTransition> transitions;
  std::string ended;          // why the loop stopped
  std::string journal_error;  // set by LoopSession::run when the journal could not be written
};
// Its JSON form (`sim --json`, the tests' traces): lftrack/records/loop_json.hpp.

// "15 no operator token, or a wrong one; 2 replayed or stale request": the nonzero counts of
// `by_reason` (an array indexed by OperatorRefusal) with their reasons, in code order ("unknown N"
// for a code this build does not know); "" when all are zero.
template <typename Counts>
std::string refusals_text(const Counts& by_reason) {
  std::string text;
  for (std::size_t i = 1; i < std::size(by_reason); ++i) {
    if (by_reason[i] == 0) continue;
    const std::string name = to_string(static_cast<OperatorRefusal>(i));
    if (!text.empty()) text += "; ";
    text += std::to_string(by_reason[i]) + " " + (name == "?" ? "unknown " + std::to_string(i) : name);
  }
  return text;
}

}  // namespace lftrack::loop
