// The chaos soak's injector: each cycle's fault drawn from the seed, and the journal's disk that
// fills (chaos_devices.hpp).

#include "chaos_devices.hpp"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <stdexcept>
#include <vector>

#include "lftrack/sim/modbus_couch_server.hpp"
#include "lftrack/sim/virtual_robot.hpp"

namespace lftrack::chaos {

namespace {

bool is_frame_fault(ChaosFault f) {
  return f >= ChaosFault::kFrameLost && f <= ChaosFault::kFrameThrows;
}
bool is_readback_fault(ChaosFault f) {
  return f >= ChaosFault::kReadbackTimeout && f <= ChaosFault::kReadbackThrows;
}
bool is_command_fault(ChaosFault f) {
  return f >= ChaosFault::kCommandTimeout && f <= ChaosFault::kCommandThrows;
}
bool is_modbus_fault(ChaosFault f) {
  return f >= ChaosFault::kModbusNoReply && f <= ChaosFault::kModbusDropConnection;
}
bool is_can_fault(ChaosFault f) {
  return f >= ChaosFault::kCanBusOff && f <= ChaosFault::kCanHeartbeatLoss;
}
bool is_surrogate_fault(ChaosFault f) {
  return f >= ChaosFault::kSurrogateStop && f <= ChaosFault::kSurrogateCough;
}

}  // namespace

ssize_t DiskThatFills::write(int fd, const void* data, std::size_t bytes) {
  if (full_.load(std::memory_order_acquire)) {
    errno = ENOSPC;
    return -1;
  }
  return ::write(fd, data, bytes);
}

Injector::Injector(std::uint64_t seed, double fault_rate, double period_s, std::int64_t segment_cycles,
                   const SafetyLimits& limits, std::shared_ptr<DiskThatFills> journal_disk)
    : random_(seed),
      side_random_(seed ^ 0x9E3779B97F4A7C15ull),
      fault_rate_(fault_rate),
      period_s_(period_s),
      segment_cycles_(segment_cycles),
      limits_(limits),
      journal_disk_(std::move(journal_disk)) {}

void Injector::count(ChaosFault f) {
  if (f == ChaosFault::kDiskFull) disk_full_wall_ = std::chrono::steady_clock::now();
  ++injected[std::size_t(f)];
}

void Injector::inject_can(ChaosFault f) {
  using sim::RobotFault;
  RobotFault fault = RobotFault::kErrorFlood;
  int undo = -1;
  std::int64_t undo_after = 0;  // cycles, and at least `undo_after_s` of wall time: the driver's
  double undo_after_s = 0;      // heartbeat timeout (0.3 s) runs on the real clock
  switch (f) {
    case ChaosFault::kCanBusOff:
      fault = RobotFault::kBusOff, undo = int(RobotFault::kControllerRestarted), undo_after = 5,
      undo_after_s = 0.5;
      break;
    case ChaosFault::kCanErrorPassive:
      fault = RobotFault::kErrorPassive, undo = int(RobotFault::kErrorActive), undo_after = 5,
      undo_after_s = 0.5;
      break;
    case ChaosFault::kCanRobotRestart:
      fault = RobotFault::kRobotRestart;
      break;
    case ChaosFault::kCanHeartbeatLoss:
      fault = RobotFault::kStopHeartbeat, undo = int(RobotFault::kResumeHeartbeat), undo_after = 20,
      undo_after_s = 1.0;
      break;
    default:
      break;
  }
  can_robot_->inject(fault);
  if (undo >= 0) {
    can_followup_ = undo;
    can_followup_at_ = cycle_ + undo_after;
    can_followup_wall_ =
        std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                               std::chrono::duration<double>(undo_after_s));
  }
  if (!can_pending_) can_pending_ = PendingCanFault{f, cycle_, std::chrono::steady_clock::now()};
}

void Injector::begin_cycle(std::int64_t cycle) {
  cycle_ = cycle;
  injection = CycleInjection{};
  const bool permit = calls.beam_permit;
  const tracking::Vector6d target = calls.target_after;
  calls = ActuatorCalls{};
  calls.beam_permit = permit;  // the device keeps its permit and its target until told otherwise
  calls.target_after = target;
  action = OperatorAction{};
  drawn_ = ChaosFault::kCount;
  if (can_followup_ >= 0 && cycle >= can_followup_at_ &&
      std::chrono::steady_clock::now() >= can_followup_wall_) {  // the bus or heartbeat comes back
    can_robot_->inject(static_cast<sim::RobotFault>(can_followup_));
    can_followup_ = -1;
  }
  // The same three draws every cycle, so that the schedule depends on the seed and the cycle
  // alone, never on what the loop did.
  const double fault_draw = draw_uniform(random_, 0, 1);
  const double kind_draw = draw_uniform(random_, 0, 1);
  const double parameter = draw_uniform(random_, 0, 1);
  if (stall_cycles_left_ > 0) {
    --stall_cycles_left_;
    injection.stalled = true;
    return;
  }
  stall_ns_ = 0;
  // The loop asks for the next exposure after its last cycle too: no fault for a cycle that
  // will not run.
  if (fault_draw >= fault_rate_ || cycle >= segment_cycles_) return;
  // Every kind that fits this segment: shifts are drawn into the patient's motion beforehand,
  // the Modbus server's faults only where there is one, a full disk once.
  std::vector<ChaosFault> kinds;
  for (std::size_t k = 0; k < kChaosFaultKinds; ++k) {
    const auto f = static_cast<ChaosFault>(k);
    if (f == ChaosFault::kPatientShift) continue;
    if (is_modbus_fault(f) && modbus_server_ == nullptr) continue;
    if (is_can_fault(f) && (can_robot_ == nullptr || can_followup_ >= 0)) continue;
    if (f == ChaosFault::kDiskFull && disk_full_at_ >= 0) continue;
    if (is_surrogate_fault(f) && !surrogate_segment_) continue;
    kinds.push_back(f);
  }
  const ChaosFault f = kinds[std::min(kinds.size() - 1, std::size_t(kind_draw * double(kinds.size())))];
  if (f == ChaosFault::kHostStall) {
    stall_cycles_left_ = int(parameter * 4);  // this cycle and up to three after it
    stall_ns_ = std::int64_t((0.2 + 2.3 * parameter) * period_s_ * 1e9);
    injection.stalled = true;
    injection.what = to_string(f);
    count(f);
  } else if (f == ChaosFault::kDiskFull) {
    disk_full_at_ = cycle;
    journal_disk_->fill();
    count(f);
  } else if (is_modbus_fault(f)) {
    const sim::CouchServerFault server_fault =
        f == ChaosFault::kModbusNoReply      ? sim::CouchServerFault::kNoReply
        : f == ChaosFault::kModbusException4 ? sim::CouchServerFault::kException4
                                             : sim::CouchServerFault::kDropConnection;
    modbus_server_->inject(server_fault, 1, sim::CouchRequestKind::kAny);
    count(f);
  } else if (is_can_fault(f)) {
    inject_can(f);
    count(f);
  } else {
    drawn_ = f;  // taken by the wrapper it is for, and counted where it applies it
  }
}

ChaosFault Injector::take_if(bool (*of_kind)(ChaosFault)) {
  if (!of_kind(drawn_)) return ChaosFault::kCount;
  const ChaosFault f = drawn_;
  drawn_ = ChaosFault::kCount;
  return f;
}
ChaosFault Injector::take_frame_fault() {
  return take_if(&is_frame_fault);
}
ChaosFault Injector::take_readback_fault() {
  return take_if(&is_readback_fault);
}
ChaosFault Injector::take_command_fault() {
  return take_if(&is_command_fault);
}
ChaosFault Injector::take_surrogate_fault() {
  return take_if(&is_surrogate_fault);
}

void Injector::throw_into_loop(const char* what) {
  threw = true;
  throw std::runtime_error(what);
}

}  // namespace lftrack::chaos
