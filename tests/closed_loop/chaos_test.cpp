// The chaos soak (issue 23): 20,000 cycles of the small closed-loop scene with faults from the
// whole catalogue at random and the invariants checked every cycle, with no violation; and the
// defect the soak found first, as a test of its own: a read-back carrying NaN.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>

#include "lftrack/chaos/chaos_soak.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "loop_fixture.hpp"

namespace lftrack::session {

using loop::GateReason;
using loop::JournalRecord;
using loop::TrackingState;
namespace {

using chaos::ChaosFault;
using chaos::ChaosOptions;
using chaos::ChaosReport;
using chaos::check_chaos_options;
using chaos::kChaosFaultKinds;
using chaos::run_chaos_soak;

// The session's couch, except that read-back number `nan_at` reports a NaN position.
class NanReadback final : public drivers::ForwardingActuator {
 public:
  NanReadback(drivers::Actuator* inner, int nan_at) : drivers::ForwardingActuator(inner), nan_at_(nan_at) {}
  drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline d) override {
    const drivers::DeviceStatus s = inner_->readback(state, d);
    if (readbacks_++ == nan_at_) state->position[1] = std::numeric_limits<double>::quiet_NaN();
    return s;
  }

 private:
  int nan_at_;
  int readbacks_ = 0;
};

TEST_F(ClosedLoop, AReadbackCarryingNanHoldsAsAnActuatorFault) {
  // Before the chaos soak found it, a NaN position with a finite target was taken as a valid
  // read-back: its NaN went into the patient's offset and the predictor's history, and the
  // cycle ended in TRACK.
  std::unique_ptr<NanReadback> wrapper;
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.hooks.wrap_actuator = [&](drivers::Actuator* inner) -> drivers::Actuator* {
    wrapper = std::make_unique<NanReadback>(inner, 31);  // the initial read-back, then one per cycle
    return wrapper.get();
  };
  const LoopRun r = run_loop(kBreathing, 40, options);
  ASSERT_EQ(r.journal.records.size(), 40u);
  const JournalRecord& at = r.journal.records[30];
  EXPECT_EQ(at.state, std::uint8_t(TrackingState::kHold));
  EXPECT_EQ(at.gate_reason, std::uint8_t(GateReason::kActuatorFault));
  EXPECT_EQ(at.command_sent, 0);
  EXPECT_EQ(at.beam_permit, 0);
  for (const JournalRecord& rec : r.journal.records)
    for (double v : rec.command) EXPECT_TRUE(std::isfinite(v)) << "cycle " << rec.cycle;
  for (std::size_t i = 0; i < 30; ++i)
    EXPECT_EQ(r.journal.records[i].state, std::uint8_t(TrackingState::kTrack)) << "cycle " << i;
}

// CI's 20,000 chaotic cycles. A fault rate of 0.1 gives about 2,000 faults: every kind many
// times over (the rarest, CAN kinds only in a third of the segments, about 8 times; as two soaks
// of 10,000 at 0.08 one of them went without a CAN error flood a few times in a hundred).
TEST_F(ClosedLoop, TwentyThousandChaoticCyclesKeepEveryInvariant) {
  Scene scene = small_scene(kBreathing, kLightFieldFrames);
  auto prepared = prepare_scene(scene, "", pool_);
  ASSERT_TRUE(prepared.ok()) << prepared.status().message();
  ChaosOptions o;
  o.seed = 23;
  o.cycles = 20000;
  o.fault_rate = 0.1;
  o.journal_dir = dir_.path() / "chaos";
  o.light_field_dir = shared_light_field_dir(*prepared);
  auto report = run_chaos_soak(*prepared, o, pool_);
  ASSERT_TRUE(report.ok()) << report.status().message();
  const ChaosReport& r = *report;
  SCOPED_TRACE(to_json(r).dump(1));
  EXPECT_EQ(r.violation_count, 0);
  EXPECT_EQ(r.cycles, 20000);
  EXPECT_GT(r.cycles_checked, 19000) << "a cycle that threw has no record";
  EXPECT_FALSE(r.interrupted);
  for (std::size_t k = 0; k < kChaosFaultKinds; ++k)
    EXPECT_GT(r.injected[k], 0) << to_string(static_cast<ChaosFault>(k)) << " never met the loop";
  EXPECT_GT(r.modbus_segments, 0);
  EXPECT_GT(r.can_segments, 0);
  EXPECT_GT(r.model_segments, 0);
  EXPECT_GT(r.surrogate_fault_cycles, 0) << "the loop found the injected surrogate faults";
  // It tracked between the faults, and the operator brought it back from HOLD and FAULT (loose
  // bounds: on a loaded host more registrations run out of their wall-clock budget).
  EXPECT_GT(r.states[std::size_t(TrackingState::kTrack)], r.cycles / 5);
  EXPECT_GT(r.commands, r.cycles / 5);
  EXPECT_GT(r.resumes_accepted, 20);
  EXPECT_GT(r.resets_accepted, 10);
  EXPECT_GT(r.operator_refused, 0) << "stale, early and wrong-id commands were sent";
  // Every journal was read back and checked (each segment's against its cycles); a full disk
  // loses the records after it.
  EXPECT_GT(r.journal_records, r.cycles * 3 / 4);
}

TEST(ChaosOptions, AbsurdValuesAreRefusedBeforeAnythingRuns) {
  ChaosOptions o;
  o.journal_dir = "out/chaos-test-never-created";
  for (double rate : {-0.1, 0.6, std::nan(""), std::numeric_limits<double>::infinity()}) {
    o.fault_rate = rate;
    EXPECT_FALSE(check_chaos_options(o).ok()) << rate;
  }
  o.fault_rate = 0.03;
  for (std::int64_t cycles : {std::int64_t(-1), std::int64_t(1'000'000'000'000)}) {  // 0: until interrupted
    o.cycles = cycles;
    EXPECT_FALSE(check_chaos_options(o).ok()) << cycles;
  }
  o.cycles = 100;
  o.segment_cycles = 5;
  EXPECT_FALSE(check_chaos_options(o).ok());
  o.segment_cycles = 2000;
  o.journal_dir.clear();
  EXPECT_FALSE(check_chaos_options(o).ok()) << "journals are required";
  EXPECT_FALSE(std::filesystem::exists("out/chaos-test-never-created"));
}

}  // namespace
}  // namespace lftrack::session
