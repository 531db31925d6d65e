// Hardware in the loop: the closed loop with the real Modbus couch driver talking to the virtual
// couch server on loopback, and with the real CAN driver talking to the virtual robot over a
// socket pair. Both track as the in-process simulation does, and every Modbus and CAN fault of
// the catalogue (docs/faults.md) holds (or stops), drops the beam and is journaled with its
// reason, with no command outside the limits.

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <ostream>
#include <thread>
#include <vector>

#include "loop_fixture.hpp"

#include "lftrack/records/loop_json.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"

namespace lftrack::session {

using loop::GateReason;
using loop::JournalRecord;
using loop::LoopSummary;
using loop::TrackingEvent;
using loop::TrackingState;

using records::to_json;
namespace {

using sim::CouchServerFault;

// The same seed and timing as in process: every cycle tracked, the same residual to within the
// protocol's rounding (2026-11-27: in process 0.383 / 0.470 mm mean / p95 of 120 cycles, over
// Modbus 0.391 / 0.473, over CAN 0.369 / 0.448, every run the same). The in-process run varied
// from run to run until the motion predictor took integer times (its p95 between 0.456 and 0.505
// mm; the protocols' rounding of each command most likely absorbed the same 1e-12 mm drift in
// the HIL runs), so these tolerances had been widened to 0.03 / 0.08 mm; they are back at 0.02 /
// 0.05.
void expect_tracks_as_in_process(const LoopSummary& in_process, const LoopSummary& hil) {
  expect_tracks_every_cycle(hil, 120);
  ASSERT_TRUE(in_process.residual_mean_mm && hil.residual_mean_mm);
  EXPECT_NEAR(*hil.residual_mean_mm, *in_process.residual_mean_mm, 0.02);
  EXPECT_NEAR(*hil.residual_p95_mm, *in_process.residual_p95_mm, 0.05);
}

// The first cycle that left TRACK (0: none); on the way, every command is finite.
std::size_t first_cycle_out_of_track(const std::vector<JournalRecord>& records) {
  std::size_t at = 0;
  for (std::size_t i = 0; i < records.size(); ++i) {
    if (at == 0 && records[i].state != std::uint8_t(TrackingState::kTrack)) at = i;
    for (double v : records[i].command) EXPECT_TRUE(std::isfinite(v)) << "cycle " << i;
  }
  return at;
}

// From `from` on: held or stopped, no beam, and nothing sent after the first of those cycles.
void expect_safe_from(const std::vector<JournalRecord>& records, std::size_t from) {
  for (std::size_t i = from; i < records.size(); ++i) {
    EXPECT_TRUE(records[i].state == std::uint8_t(TrackingState::kHold) ||
                records[i].state == std::uint8_t(TrackingState::kFault))
        << "never back to TRACK without the operator, cycle " << i;
    EXPECT_EQ(records[i].beam_permit, 0) << i;
    if (i > from) {
      EXPECT_EQ(records[i].command_sent, 0) << "held: nothing sent, cycle " << i;
    }
  }
}

TEST_F(ClosedLoop, HardwareInTheLoopTracksAsTheInProcessSimulation) {
  const LoopRun in_process = run_loop(kBreathing, 120);
  LoopSessionOptions hil;
  hil.simulator = sim_devices::room_simulator();
  hil.hil = HilProtocol::kModbus;
  const LoopRun over_modbus = run_loop(kBreathing, 120, hil);
  // The protocol rounds targets to 1 um and 1 urad.
  expect_tracks_as_in_process(in_process.summary, over_modbus.summary);
  EXPECT_EQ(over_modbus.summary.commands, in_process.summary.commands);
  ASSERT_EQ(over_modbus.journal.records.size(), 120u);
  double largest_readback_difference_mm = 0;
  for (std::size_t i = 0; i < 120; ++i)
    largest_readback_difference_mm = std::max(
        largest_readback_difference_mm,
        std::abs(over_modbus.journal.records[i].readback[0] - in_process.journal.records[i].readback[0]));
  // The registration's wall-clock budget may end one cycle's search at a different evaluation in
  // the two runs; the couch then takes a slightly different path for a few cycles.
  EXPECT_LT(largest_readback_difference_mm, 0.5) << "the couch moved the same way through the protocol";
}

// A fault on the read-back holds (HOLD, reason in the gate's record); on a command, the couch
// may or may not have taken it, so the loop stops safely (FAULT, event "device fault").
struct ModbusFaultCase {
  const char* name;
  CouchServerFault fault;
  sim::CouchRequestKind kind;
  TrackingState safe_state;
  GateReason reason;  // for HOLD
};

void PrintTo(const ModbusFaultCase& c, std::ostream* os) {
  *os << c.name;
}

class HilModbusFault : public ClosedLoop, public ::testing::WithParamInterface<ModbusFaultCase> {};

TEST_P(HilModbusFault, HoldsTheCouchDropsTheBeamAndJournalsTheReason) {
  const ModbusFaultCase& c = GetParam();
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.hil = HilProtocol::kModbus;
  constexpr std::int64_t kFaultAtRequest = 40;  // about cycle 20: readback and command each cycle
  const LoopRun r = run_loop(kBreathing, 45, options, kLightFieldFrames, [&](LoopSession& session) {
    sim::ModbusCouchServer* server = sim_devices::modbus_couch_server(session);
    return std::thread([server, c] {
      const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60);
      while (server->requests() < kFaultAtRequest && std::chrono::steady_clock::now() < until)
        std::this_thread::sleep_for(std::chrono::microseconds(200));
      server->inject(c.fault, 1, c.kind);
    });
  });
  const LoopSummary& s = r.summary;
  SCOPED_TRACE(to_json(s).dump());
  EXPECT_EQ(s.holds + s.faults, 1) << "one fault, one safe state; nothing resumes without the operator";
  ASSERT_EQ(r.journal.records.size(), 45u);
  // No command beyond the scene's per-cycle limit, ever (the first cycle's is the set-up move).
  for (std::size_t i = 1; i < r.journal.records.size(); ++i) {
    const double* command = r.journal.records[i].command;
    EXPECT_LE(std::max({std::abs(command[0]), std::abs(command[1]), std::abs(command[2])}),
              scene_->scene.safety.max_step_mm + 1e-9)
        << "cycle " << i;
  }
  const std::size_t held_at = first_cycle_out_of_track(r.journal.records);
  ASSERT_GT(held_at, 15u);
  const JournalRecord& entry = r.journal.records[held_at];
  EXPECT_EQ(entry.state, std::uint8_t(c.safe_state));
  if (c.safe_state == TrackingState::kHold) {
    EXPECT_EQ(entry.gate_reason, std::uint8_t(c.reason)) << to_string(GateReason(entry.gate_reason));
  } else {
    EXPECT_EQ(entry.event, 1 + int(TrackingEvent::kDeviceFault));
  }
  for (std::size_t i = held_at; i < r.journal.records.size(); ++i)
    EXPECT_EQ(r.journal.records[i].state, std::uint8_t(c.safe_state)) << i;
  expect_safe_from(r.journal.records, held_at);
}

constexpr auto kRead = sim::CouchRequestKind::kReadback;
constexpr auto kWrite = sim::CouchRequestKind::kCommand;
constexpr auto kHold = TrackingState::kHold;
constexpr auto kFault = TrackingState::kFault;
constexpr auto kNoReadback = GateReason::kActuatorFault;

INSTANTIATE_TEST_SUITE_P(
    FaultCatalogue, HilModbusFault,
    ::testing::Values(
        ModbusFaultCase{"NoReplyToReadback", CouchServerFault::kNoReply, kRead, kHold, kNoReadback},
        ModbusFaultCase{"NoReplyToCommand", CouchServerFault::kNoReply, kWrite, kFault, GateReason::kOk},
        ModbusFaultCase{"Exception4OnReadback", CouchServerFault::kException4, kRead, kHold, kNoReadback},
        ModbusFaultCase{"Exception4OnCommand", CouchServerFault::kException4, kWrite, kFault,
                        GateReason::kOk},
        ModbusFaultCase{"Exception6OnReadback", CouchServerFault::kException6, kRead, kHold, kNoReadback},
        ModbusFaultCase{"WrongUnitOnReadback", CouchServerFault::kWrongUnit, kRead, kHold, kNoReadback},
        ModbusFaultCase{"WrongUnitOnCommand", CouchServerFault::kWrongUnit, kWrite, kFault, GateReason::kOk},
        ModbusFaultCase{"DroppedConnection", CouchServerFault::kDropConnection, kRead, kHold, kNoReadback},
        ModbusFaultCase{"ReadbackMismatch", CouchServerFault::kReadbackMismatch, kRead, kHold,
                        GateReason::kReadbackMismatch}),
    [](const ::testing::TestParamInfo<ModbusFaultCase>& param) { return std::string(param.param.name); });

using sim::RobotFault;

TEST_F(ClosedLoop, HardwareInTheLoopOverCanTracksAsTheInProcessSimulation) {
  const LoopRun in_process = run_loop(kBreathing, 120);
  LoopSessionOptions hil;
  hil.simulator = sim_devices::room_simulator();
  hil.hil = HilProtocol::kCan;
  const LoopRun over_can = run_loop(kBreathing, 120, hil);
  // Corrections cross the link in 1 um and 10 urad steps.
  expect_tracks_as_in_process(in_process.summary, over_can.summary);
}

struct CanFaultCase {
  const char* name;
  std::vector<RobotFault> faults;
};

void PrintTo(const CanFaultCase& c, std::ostream* os) {
  *os << c.name;
}

class HilCanFault : public ClosedLoop, public ::testing::WithParamInterface<CanFaultCase> {};

// The loop runs until the robot has lost the beam permit (the loop's HOLD), then a while more,
// and is stopped: on the simulated clock it outruns the wall clock, and a fault that shows after a
// real-time timeout (a heartbeat missing for 1 s on the simulated clock) came after the last of a fixed number of
// cycles on a quiet host, where the loop never held (the robot's permit then dropped only with
// the end of the run).
TEST_P(HilCanFault, HoldsDropsTheBeamOnTheRobotAndNothingResumesSilently) {
  const CanFaultCase& c = GetParam();
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.hil = HilProtocol::kCan;
  bool beam_before = false, beam_after = true;
  const LoopRun r = run_loop(kBreathing, 0, options, kLightFieldFrames, [&](LoopSession& session) {
    sim::VirtualRobot* robot = sim_devices::virtual_robot(session);
    return std::thread([&session, robot, &c, &beam_before, &beam_after] {
      using std::chrono::steady_clock;
      const auto until = steady_clock::now() + std::chrono::seconds(60);
      while (robot->corrections() < 15 && steady_clock::now() < until)
        std::this_thread::sleep_for(std::chrono::microseconds(200));
      beam_before = robot->beam_permit();
      for (RobotFault f : c.faults) robot->inject(f);
      // The loop holds within a cycle or two of seeing the fault (a missing heartbeat: its 1 s on the simulated clock).
      const auto hold_until = steady_clock::now() + std::chrono::seconds(30);
      while (robot->beam_permit() && steady_clock::now() < hold_until)
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      beam_after = robot->beam_permit();
      // Cycles after the hold, in which nothing may resume by itself.
      std::this_thread::sleep_for(std::chrono::milliseconds(300));
      session.request_stop();
    });
  });
  const LoopSummary& s = r.summary;
  SCOPED_TRACE(to_json(s).dump());
  EXPECT_TRUE(beam_before) << "the robot had the beam permit while tracking";
  EXPECT_FALSE(beam_after) << "the robot lost it on the fault";
  EXPECT_EQ(s.holds, 1);
  EXPECT_LE(s.faults, 1) << "a condition that lasts escalates from HOLD to FAULT (the gate's STOP)";
  const std::size_t held_at = first_cycle_out_of_track(r.journal.records);
  ASSERT_GT(held_at, 10u);
  EXPECT_EQ(r.journal.records[held_at].state, std::uint8_t(TrackingState::kHold));
  // The fault meets the cycle at its read-back, or between the read-back and the command, which
  // the driver then refuses unsent.
  const std::uint8_t reason = r.journal.records[held_at].gate_reason;
  EXPECT_TRUE(reason == std::uint8_t(GateReason::kActuatorFault) || reason == std::uint8_t(GateReason::kCommandRefused))
      << to_string(static_cast<GateReason>(reason));
  expect_safe_from(r.journal.records, held_at);
}

INSTANTIATE_TEST_SUITE_P(
    FaultCatalogue, HilCanFault,
    ::testing::Values(CanFaultCase{"BusOff", {RobotFault::kBusOff}},
                      CanFaultCase{"BusOffThenRestart",
                                   {RobotFault::kBusOff, RobotFault::kControllerRestarted}},
                      CanFaultCase{"ErrorPassive", {RobotFault::kErrorPassive}},
                      CanFaultCase{"RobotRestart", {RobotFault::kRobotRestart}},
                      CanFaultCase{"MissingHeartbeat", {RobotFault::kStopHeartbeat}},
                      CanFaultCase{"ErrorFrameFlood", {RobotFault::kErrorFlood}}),
    [](const ::testing::TestParamInfo<CanFaultCase>& param) { return std::string(param.param.name); });

}  // namespace
}  // namespace lftrack::session
