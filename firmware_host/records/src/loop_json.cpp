// The JSON forms of the loop's summary, its accuracy reports and a pose delta.

#include "lftrack/records/loop_json.hpp"

#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/tracking/pose.hpp"

namespace lftrack::records {

using loop::CommandLatencyReport;
using loop::GateDecision;
using loop::key_of;
using loop::kLatencyLinks;
using loop::LatencyChainReport;
using loop::LatencyLink;
using loop::LinkLatency;
using loop::LoopSummary;
using loop::LoopTransition;
using loop::OperatorRefusal;
using loop::TargetResidualReport;
using loop::TrackingState;

nlohmann::json pose_delta_json(const double d[6]) {
  using tracking::rad_to_deg;
  return {{"translation_mm", {d[0], d[1], d[2]}}, {"rotation_deg", {rad_to_deg(d[3]), rad_to_deg(d[4]), rad_to_deg(d[5])}}};
}

nlohmann::json to_json(const LinkLatency& l) {
  return {{"p50", l.p50_ms}, {"p95", l.p95_ms}, {"p99", l.p99_ms}, {"max", l.max_ms}};
}

nlohmann::json to_json(const LatencyChainReport& r) {
  nlohmann::json j;
  j["commands"] = r.commands;
  for (int i = 0; i < kLatencyLinks; ++i)
    j[key_of(static_cast<LatencyLink>(i))] = to_json(r.links[std::size_t(i)]);
  j["total"] = to_json(r.total);
  return j;
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
  j["latency_chain_ms"] = s.latency_chain ? to_json(*s.latency_chain) : nlohmann::json(nullptr);
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
  j["imaging"] = {{"mode", s.imaging},
                  {"xray_pairs", s.xray_pairs},
                  {"early_pairs", s.early_pairs},
                  {"pairs_per_minute", s.pairs_per_minute},
                  {"dose_per_pair_mGy", s.dose_per_pair_mGy},
                  {"dose_mGy_per_minute", s.dose_mGy_per_minute},
                  {"model_cycles", s.model_cycles},
                  {"model_checks", s.model_checks},
                  {"model_misses", s.model_misses},
                  {"model_check_mm", s.model_checks > 0 ? nlohmann::json{{"p50", s.model_check_p50_mm},
                                                                         {"p95", s.model_check_p95_mm}}
                                                        : nlohmann::json(nullptr)},
                  {"model_not_ready", s.model_not_ready}};
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

nlohmann::json to_json(const TargetResidualReport& r) {
  return {{"cycles", r.cycles},
          {"translation_mm", {{"mean", r.translation_mean_mm}, {"sd", r.translation_sd_mm}}},
          {"rotation_deg", {{"mean", r.rotation_mean_deg}, {"sd", r.rotation_sd_deg}}},
          {"error_3d_mm", {{"mean", r.error_3d_mean_mm}, {"p95", r.error_3d_p95_mm}, {"max", r.error_3d_max_mm}}},
          {"share_over_1mm", r.share_over_1mm},
          {"share_over_2mm", r.share_over_2mm},
          {"beam_on",
           {{"cycles", r.beam_on_cycles},
            {"share_over_1mm", r.beam_on_share_over_1mm},
            {"share_over_2mm", r.beam_on_share_over_2mm}}}};
}

nlohmann::json to_json(const CommandLatencyReport& r) {
  return {{"commands", r.commands}, {"p50", r.p50_ms}, {"p95", r.p95_ms}, {"p99", r.p99_ms}, {"max", r.max_ms}};
}

}  // namespace lftrack::records
