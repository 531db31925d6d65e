// The chaos soak's faults by name, its options' ranges, and its report as JSON (chaos_soak.hpp).

#include <cmath>
#include <filesystem>
#include <string>

#include "lftrack/chaos/chaos_soak.hpp"
#include "lftrack/loop/tracking_states.hpp"

namespace lftrack::chaos {

const char* to_string(ChaosFault fault) {
  switch (fault) {
    case ChaosFault::kFrameLost:
      return "frame_lost";
    case ChaosFault::kFrameLate:
      return "frame_late";
    case ChaosFault::kFrameStale:
      return "frame_stale";
    case ChaosFault::kFrameSkewed:
      return "frame_skewed";
    case ChaosFault::kFrameBlank:
      return "frame_blank";
    case ChaosFault::kFrameSaturated:
      return "frame_saturated";
    case ChaosFault::kFrameTorn:
      return "frame_torn";
    case ChaosFault::kFrameDisconnected:
      return "frame_disconnected";
    case ChaosFault::kFrameDeviceFault:
      return "frame_device_fault";
    case ChaosFault::kFrameThrows:
      return "frame_throws";
    case ChaosFault::kReadbackTimeout:
      return "readback_timeout";
    case ChaosFault::kReadbackDisconnected:
      return "readback_disconnected";
    case ChaosFault::kReadbackFaultFlag:
      return "readback_fault_flag";
    case ChaosFault::kReadbackMismatch:
      return "readback_mismatch";
    case ChaosFault::kReadbackNonFinite:
      return "readback_non_finite";
    case ChaosFault::kReadbackThrows:
      return "readback_throws";
    case ChaosFault::kCommandTimeout:
      return "command_timeout";
    case ChaosFault::kCommandDisconnected:
      return "command_disconnected";
    case ChaosFault::kCommandFault:
      return "command_fault";
    case ChaosFault::kCommandThrows:
      return "command_throws";
    case ChaosFault::kModbusNoReply:
      return "modbus_no_reply";
    case ChaosFault::kModbusException4:
      return "modbus_exception_4";
    case ChaosFault::kModbusDropConnection:
      return "modbus_drop_connection";
    case ChaosFault::kCanBusOff:
      return "can_bus_off";
    case ChaosFault::kCanErrorPassive:
      return "can_error_passive";
    case ChaosFault::kCanErrorFlood:
      return "can_error_flood";
    case ChaosFault::kCanRobotRestart:
      return "can_robot_restart";
    case ChaosFault::kCanHeartbeatLoss:
      return "can_heartbeat_loss";
    case ChaosFault::kHostStall:
      return "host_stall";
    case ChaosFault::kDiskFull:
      return "disk_full";
    case ChaosFault::kPatientShift:
      return "patient_shift";
    case ChaosFault::kSurrogateStop:
      return "surrogate_stop";
    case ChaosFault::kSurrogateFreeze:
      return "surrogate_freeze";
    case ChaosFault::kSurrogateSpike:
      return "surrogate_spike";
    case ChaosFault::kSurrogateNonFinite:
      return "surrogate_non_finite";
    case ChaosFault::kSurrogateCough:
      return "surrogate_cough";
    case ChaosFault::kCount:
      break;
  }
  return "none";
}

Status check_chaos_options(const ChaosOptions& o) {
  constexpr std::int64_t kMaxCycles = 1'000'000'000;
  if (o.cycles < 0 || o.cycles > kMaxCycles)
    return invalid_argument("chaos: cycles must be 0 (until interrupted) to " + std::to_string(kMaxCycles));
  if (o.segment_cycles < 10 || o.segment_cycles > 1'000'000)
    return invalid_argument("chaos: a segment must be 10 to 1000000 cycles");
  if (!std::isfinite(o.fault_rate) || o.fault_rate < 0 || o.fault_rate > 0.5)
    return invalid_argument("chaos: the fault rate must be a probability per cycle from 0 to 0.5");
  if (o.journal_dir.empty())
    return invalid_argument("chaos: a folder for the segments' journals is required");
  std::error_code ec;
  if (std::filesystem::exists(o.journal_dir, ec) && !std::filesystem::is_directory(o.journal_dir, ec))
    return invalid_argument("chaos: " + o.journal_dir.string() + " is not a folder");
  return {};
}

nlohmann::json to_json(const ChaosReport& r) {
  nlohmann::json j;
  j["seed"] = r.seed;
  j["cycles"] = r.cycles;
  j["cycles_checked"] = r.cycles_checked;
  j["interrupted"] = r.interrupted;
  j["journal_dir"] = r.journal_dir.string();
  j["segments"] = r.segments;
  j["modbus_segments"] = r.modbus_segments;
  j["can_segments"] = r.can_segments;
  j["model_segments"] = r.model_segments;
  j["surrogate_fault_cycles"] = r.surrogate_fault_cycles;
  nlohmann::json injected = nlohmann::json::object();
  std::int64_t total = 0;
  for (std::size_t k = 0; k < kChaosFaultKinds; ++k) {
    injected[to_string(static_cast<ChaosFault>(k))] = r.injected[k];
    total += r.injected[k];
  }
  j["faults_injected"] = injected;
  j["faults_injected_total"] = total;
  nlohmann::json states = nlohmann::json::object();
  for (std::size_t s = 0; s < r.states.size(); ++s)
    states[to_string(static_cast<TrackingState>(s))] = r.states[s];
  j["states"] = states;
  j["commands"] = r.commands;
  j["holds"] = r.holds;
  j["faults"] = r.faults;
  j["overruns"] = r.overruns;
  j["resumes_accepted"] = r.resumes_accepted;
  j["resets_accepted"] = r.resets_accepted;
  j["operator_commands_refused"] = r.operator_refused;
  j["journal_records_checked"] = r.journal_records;
  j["violation_count"] = r.violation_count;
  nlohmann::json violations = nlohmann::json::array();
  for (const ChaosViolation& v : r.violations)
    violations.push_back({{"segment", v.segment}, {"cycle", v.cycle}, {"what", v.what}});
  j["violations"] = violations;
  j["wall_s"] = r.wall_s;
  return j;
}

}  // namespace lftrack::chaos
