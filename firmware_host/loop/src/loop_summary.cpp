// The summary of a run: statistics gathered over the cycles, and its JSON form.

#include <nlohmann/json.hpp>

#include "lftrack/tracking/pose.hpp"
#include "loop_impl.hpp"

namespace lftrack::host {

void TrackingLoop::Impl::finish_summary(std::int64_t aligned_at, std::uint64_t allocations_at_warmup,
                                        std::uint64_t allocations_at_end) {
  LoopSummary& s = summary;
  if (residual_mm.count() > 0) {
    s.residual_mean_mm = residual_mm.mean();
    s.residual_p95_mm = residual_mm.quantile(0.95);
    s.residual_max_mm = residual_mm.max();
  }
  s.target_residual = accuracy.target_residual();
  s.command_latency = accuracy.latency();
  s.simulated_clock = settings.simulated_clock;
  s.view_check_every =
      parts.view_agreement == nullptr ? -1 : (settings.judge_tracking ? settings.view_check_every : 0);
  s.cycle_p50_ms = cycle_ms.quantile(0.5);
  s.cycle_p95_ms = cycle_ms.quantile(0.95);
  s.cycle_p99_ms = cycle_ms.quantile(0.99);
  s.cycle_max_ms = cycle_ms.max();
  s.registration_p50_ms = registration_ms.quantile(0.5);
  s.registration_p95_ms = registration_ms.quantile(0.95);
  s.registration_max_ms = registration_ms.max();
  s.acquire_p95_ms = acquire_ms.quantile(0.95);
  s.acquire_max_ms = acquire_ms.max();
  s.readback_p50_ms = readback_ms.quantile(0.5);
  s.readback_p99_ms = readback_ms.quantile(0.99);
  s.preprocess_p95_ms = preprocess_ms.quantile(0.95);
  s.preprocess_max_ms = preprocess_ms.max();
  s.verdict_checks = verdict_check_ms.count();
  s.verdict_check_p50_ms = verdict_check_ms.quantile(0.5);
  s.verdict_check_p95_ms = verdict_check_ms.quantile(0.95);
  s.verdict_check_max_ms = verdict_check_ms.max();
  s.view_checks = view_check_ms.count();
  s.view_checks_refused = view_checks_refused;
  s.view_checks_out_of_time = view_checks_out_of_time;
  s.view_check_p50_ms = view_check_ms.quantile(0.5);
  s.view_check_max_ms = view_check_ms.max();
  s.evaluations_mean =
      registration_ms.count() > 0 ? evaluations_sum / double(registration_ms.count()) : 0;
  if (parts.allocation_count != nullptr && aligned_at >= 0) {
    const std::int64_t counted = s.cycles - (aligned_at + settings.warmup_cycles);
    if (counted > 0) {
      s.allocation_cycles = counted;
      s.allocations_per_cycle = double(allocations_at_end - allocations_at_warmup) / double(counted);
    }
  }
}

nlohmann::json pose_delta_json(const double d[6]) {
  using tracking::rad_to_deg;
  return {{"translation_mm", {d[0], d[1], d[2]}}, {"rotation_deg", {rad_to_deg(d[3]), rad_to_deg(d[4]), rad_to_deg(d[5])}}};
}

nlohmann::json to_json(const LoopSummary& s) {
  nlohmann::json j;
  j["cycles"] = s.cycles;
  auto opt = [](const std::optional<double>& v) { return v ? nlohmann::json(*v) : nlohmann::json(nullptr); };
  j["residual_mm"] = {
      {"mean", opt(s.residual_mean_mm)}, {"p95", opt(s.residual_p95_mm)}, {"max", opt(s.residual_max_mm)}};
  j["target_residual"] = s.target_residual ? to_json(*s.target_residual) : nlohmann::json(nullptr);
  j["latency_exposure_to_ack_ms"] = s.command_latency ? to_json(*s.command_latency) : nlohmann::json(nullptr);
  if (s.command_latency)  // on the simulated clock an acknowledgement is the command's deadline
    j["latency_exposure_to_ack_ms"]["clock"] = s.simulated_clock ? "simulated: the command deadline, not a measurement"
                                                                 : "real";
  j["cycle_ms"] = {
      {"p50", s.cycle_p50_ms}, {"p95", s.cycle_p95_ms}, {"p99", s.cycle_p99_ms}, {"max", s.cycle_max_ms}};
  j["registration_ms"] = {
      {"p50", s.registration_p50_ms}, {"p95", s.registration_p95_ms}, {"max", s.registration_max_ms}};
  j["acquire_ms"] = {{"p95", s.acquire_p95_ms}, {"max", s.acquire_max_ms}};
  j["preprocess_ms"] = {{"p95", s.preprocess_p95_ms}, {"max", s.preprocess_max_ms}};
  j["verdict_check_ms"] = {{"checks", s.verdict_checks},
                           {"p50", s.verdict_check_p50_ms},
                           {"p95", s.verdict_check_p95_ms},
                           {"max", s.verdict_check_max_ms}};
  j["view_check"] = {{"every_tracking_cycles", s.view_check_every},
                     {"checks", s.view_checks},
                     {"refused", s.view_checks_refused},
                     {"out_of_time", s.view_checks_out_of_time},
                     {"p50_ms", s.view_check_p50_ms},
                     {"max_ms", s.view_check_max_ms}};
  j["readback_ms"] = {{"p50", s.readback_p50_ms}, {"p99", s.readback_p99_ms}};
  j["evaluations_mean"] = s.evaluations_mean;
  j["overruns"] = s.overruns;
  j["skipped_periods"] = s.skipped_periods;
  j["holds"] = s.holds;
  j["faults"] = s.faults;
  j["commands"] = s.commands;
  j["operator_commands_refused"] = s.operator_refused;
  nlohmann::json refused_by_reason = nlohmann::json::object();
  for (std::size_t i = 1; i < s.operator_refused_by_reason.size(); ++i)
    if (s.operator_refused_by_reason[i] > 0)
      refused_by_reason[to_string(static_cast<OperatorRefusal>(i))] = s.operator_refused_by_reason[i];
  j["operator_commands_refused_by_reason"] = refused_by_reason;
  j["aligned"] = s.aligned;
  j["align_ms"] = s.align_ms;
  j["allocations_per_cycle"] = opt(s.allocations_per_cycle);
  j["allocation_cycles"] = s.allocation_cycles;
  nlohmann::json states;
  for (int i = 0; i < 5; ++i) states[to_string(static_cast<TrackingState>(i))] = s.states[std::size_t(i)];
  j["states"] = states;
  nlohmann::json decisions;
  for (int i = 0; i < 4; ++i)
    decisions[to_string(static_cast<GateDecision>(i))] = s.decisions[std::size_t(i)];
  j["gate"] = decisions;
  nlohmann::json transitions = nlohmann::json::array();
  for (const LoopTransition& t : s.transitions)
    transitions.push_back(
        {{"cycle", t.cycle}, {"from", to_string(t.from)}, {"to", to_string(t.to)}, {"reason", t.reason}});
  j["transitions"] = transitions;
  j["ended"] = s.ended;
  if (!s.journal_error.empty()) j["journal_error"] = s.journal_error;
  return j;
}

}  // namespace lftrack::host
