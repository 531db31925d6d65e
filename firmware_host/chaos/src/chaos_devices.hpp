#pragma once
// The chaos soak's parts (chaos_soak.hpp), private to the chaos library: the injector that
// draws each cycle's fault from the seed, the frame-source and actuator wrappers that inject it
// and log what really passed, the operator who answers HOLDs at random, and the journal's
// disk-full switch.

#include <atomic>
#include <cstdint>
#include <memory>
#include <random>

#include "lftrack/chaos/chaos_invariants.hpp"
#include "lftrack/chaos/chaos_soak.hpp"
#include "lftrack/drivers/forwarding_actuator.hpp"
#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/drivers/surrogate_source.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/safety_gate.hpp"

#include <chrono>
#include <optional>

namespace lftrack::sim {
class ModbusCouchServer;
class VirtualRobot;
}  // namespace lftrack::sim

namespace lftrack::chaos {

// A number drawn uniformly from [lo, hi).
inline double draw_uniform(std::mt19937_64& random, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(random);
}

// A segment's journal disk: write(2) until the injector fills it, then ENOSPC.
class DiskThatFills final : public loop::JournalSink {
 public:
  ssize_t write(int fd, const void* data, std::size_t bytes) override;
  void fill() { full_.store(true, std::memory_order_release); }

 private:
  std::atomic<bool> full_{false};
};

// Draws one fault (or none) per cycle and keeps what met the loop. The frame wrapper starts each
// cycle (begin_cycle, from request_exposure); the wrappers take the fault of their kind once.
class Injector {
 public:
  // `segment_cycles`: the cycles the segment will run (none is drawn for a later one); the
  // fault sizes (late, skewed, mismatched) are drawn beyond `limits`.
  Injector(std::uint64_t seed, double fault_rate, double period_s, std::int64_t segment_cycles,
           const SafetyLimits& limits, std::shared_ptr<DiskThatFills> journal_disk);
  const SafetyLimits& limits() const { return limits_; }
  // No fault is drawn for any later cycle (the segment is being stopped).
  void end_draws() { segment_cycles_ = 0; }
  // A fault that met the loop: counted in `injected`.
  void count(ChaosFault fault);
  // A device wrapper's injected exception: marks `threw` (the invariants then expect the loop to
  // have caught it) and throws `what` as a std::runtime_error.
  [[noreturn]] void throw_into_loop(const char* what);
  // A Modbus segment's server or a CAN segment's robot (their faults become kinds to draw); set
  // before the first cycle.
  void set_modbus_server(sim::ModbusCouchServer* server) { modbus_server_ = server; }
  void set_can_robot(sim::VirtualRobot* robot) { can_robot_ = robot; }
  // A segment that images on demand: the surrogate's faults become kinds to draw.
  void set_surrogate_segment() { surrogate_segment_ = true; }
  // The CAN fault injected and not yet seen to hold the loop.
  struct PendingCanFault {
    ChaosFault fault;
    std::int64_t cycle;
    std::chrono::steady_clock::time_point wall;
  };
  const std::optional<PendingCanFault>& can_fault_pending() const { return can_pending_; }
  void clear_can_fault() { can_pending_.reset(); }
  void begin_cycle(std::int64_t cycle);
  std::int64_t cycle() const { return cycle_; }
  // The fault for this device this cycle, taken once (kCount: none).
  ChaosFault take_frame_fault();
  ChaosFault take_readback_fault();
  ChaosFault take_command_fault();
  ChaosFault take_surrogate_fault();
  std::int64_t stall_ns() const { return stall_ns_; }
  bool disk_full_injected() const { return disk_full_at_ >= 0; }
  std::int64_t disk_full_at() const { return disk_full_at_; }
  std::chrono::steady_clock::time_point disk_full_wall() const { return disk_full_wall_; }

  CycleInjection injection;  // this cycle's, filled by the wrappers
  ActuatorCalls calls;       // this cycle's actuator calls (beam permit carried across cycles)
  OperatorAction action;     // this cycle's operator
  std::array<std::int64_t, kChaosFaultKinds> injected{};
  // An exception was thrown into the loop; since then, was the actuator held and the beam dropped?
  bool threw = false, held_after_throw = false, beam_dropped_after_throw = false;
  // For what happens inside a fault or an operator's choice: a stream apart from the schedule's,
  // so that the schedule never depends on what the loop did.
  std::mt19937_64& random() { return side_random_; }

 private:
  std::mt19937_64 random_, side_random_;
  double fault_rate_;
  double period_s_;
  void inject_can(ChaosFault fault);
  ChaosFault take_if(bool (*of_kind)(ChaosFault));
  sim::ModbusCouchServer* modbus_server_ = nullptr;
  sim::VirtualRobot* can_robot_ = nullptr;
  bool surrogate_segment_ = false;
  std::optional<PendingCanFault> can_pending_;
  int can_followup_ = -1;              // a sim::RobotFault that undoes the last one, or -1
  std::int64_t can_followup_at_ = -1;  // at this cycle, and not before this wall time
  std::chrono::steady_clock::time_point can_followup_wall_{};
  std::int64_t segment_cycles_;
  SafetyLimits limits_;
  std::int64_t cycle_ = -1;
  ChaosFault drawn_ = ChaosFault::kCount;
  int stall_cycles_left_ = 0;
  std::int64_t stall_ns_ = 0;
  std::shared_ptr<DiskThatFills> journal_disk_;  // the segment journal's (never null)
  std::int64_t disk_full_at_ = -1;
  std::chrono::steady_clock::time_point disk_full_wall_{};
};

class ChaosFrameSource final : public drivers::FrameSource {
 public:
  ChaosFrameSource(drivers::FrameSource* inner, Injector* injector, std::int64_t period_ns)
      : inner_(inner), injector_(injector), period_ns_(period_ns) {}
  Status open(drivers::FramePair* pair) override { return inner_->open(pair); }
  void request_exposure(std::int64_t exposure_time_ns) override;
  void no_exposure(std::int64_t cycle_time_ns) override;
  bool exposes_on_request() const override { return inner_->exposes_on_request(); }
  drivers::DeviceStatus acquire(drivers::FramePair* pair, drivers::Deadline deadline) override;
  bool live() const override { return inner_->live(); }
  void close() override { inner_->close(); }

 private:
  drivers::FrameSource* inner_;
  Injector* injector_;
  std::int64_t period_ns_;
  std::int64_t first_exposure_ns_ = -1;
  std::int64_t begun_cycle_ = -1;  // a cycle's faults are drawn once, whether it exposes or not
  void begin_cycle_at(std::int64_t time_ns);
};

// The session's actuator with the cycle's actuator fault injected; open, close and the read-back
// order pass through.
class ChaosActuator final : public drivers::ForwardingActuator {
 public:
  ChaosActuator(drivers::Actuator* inner, Injector* injector)
      : ForwardingActuator(inner), injector_(injector) {}
  drivers::DeviceStatus command(const tracking::Vector6d& correction, drivers::Deadline deadline) override;
  drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline deadline) override;
  void hold() override;
  void set_beam_permit(bool permit) override;

 private:
  Injector* injector_;
  tracking::Vector6d known_target_ = tracking::Vector6d::Zero();  // the device's target, as it last told us
  std::int64_t readback_cycle_ = -1;  // the cycle whose first read-back has been taken
};

// The session's breathing surrogate with the cycle's surrogate fault injected into the readings it
// gives: a stream that stops or freezes for some cycles, one reading that spikes by three times
// `jump` or is NaN, a cough the target does not follow. Read once per cycle, after the frame
// wrapper has begun it.
class ChaosSurrogate final : public drivers::SurrogateSource {
 public:
  ChaosSurrogate(drivers::SurrogateSource* inner, Injector* injector, double jump)
      : inner_(inner), injector_(injector), jump_(jump) {}
  Status open() override { return inner_->open(); }
  void close() override { inner_->close(); }
  int read(std::int64_t now_ns, drivers::SurrogateReading* out, int capacity) override;

 private:
  drivers::SurrogateSource* inner_;
  Injector* injector_;
  double jump_;
  ChaosFault active_ = ChaosFault::kCount;  // a fault that lasts some cycles
  int cycles_left_ = 0, cough_cycle_ = 0;
  double last_given_ = 0;
};

// An operator who answers each HOLD or FAULT after a random 0.2-3 s (a resume or reset naming
// its id; one time in ten first naming another id or sending the other word), retries 0.5 s
// after a refusal, and now and then sends a stale resume while tracking. Judges like the control
// socket (judge_operator_request, ids required).
class ChaosOperator final : public loop::OperatorInput {
 public:
  explicit ChaosOperator(Injector* injector) : injector_(injector) {}
  void poll(const OperatorView& view, OperatorPoll* out) override;
  bool unattended() const override { return true; }

 private:
  Injector* injector_;
  std::uint32_t planned_for_ = 0;  // the hold id the current plan answers
  double answer_at_s_ = 0;         // hold age at which to answer
  bool mistake_ = false;           // the next answer names another id or the other word
  bool answered_ = false;
  std::uint32_t last_hold_id_ = 0;
};

}  // namespace lftrack::chaos
