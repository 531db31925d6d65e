// The simulated closed loop end to end on a small version of the built-in scene (0.8 mm
// detector pixels, small light fields; frames from a separate finer field, or ray-cast): tracking
// error, states, the journal's contents, a sudden shift with an operator resume, lost frames,
// and zero heap allocations in 1,000 steady-state cycles.

#include <gtest/gtest.h>

#include <string>

#include "lftrack/host/allocation_counter.hpp"
#include "lftrack/host/sim_session.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::host {
namespace {

const char* kLightFieldFrames =
    "sim:\n  renderer: lightfield\n  light_field:\n    resolution: [16, 16, 96, 144]\n";
const char* kRayCastFrames = "sim:\n  renderer: siddon\n";

// The built-in scene with 0.8 mm detector pixels (a quarter of the rays), the frames' renderer
// and the motion given.
Scene small_scene(const std::string& motion_yaml, const std::string& frames_yaml) {
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  for (const char* from : {"    rows: 512\n    cols: 512\n    pitch_mm: 0.4\n"}) {
    for (std::size_t at = text.find(from); at != std::string::npos; at = text.find(from))
      text.replace(at, std::string(from).size(), "    rows: 256\n    cols: 256\n    pitch_mm: 0.8\n");
  }
  const auto cut = [&](const std::string& key) {
    const std::size_t at = text.find(key);
    if (at != std::string::npos) text.erase(at);
  };
  cut("tracking:");  // everything from here on is replaced
  text +=
      "tracking:\n  renderer: lightfield\n  light_field:\n    resolution: [12, 12, 64, 96]\n  similarity: "
      "mi\n" +
      frames_yaml + "  photons_per_pixel: 20000\n  detector_blur_px: 0.5\n" +
      "loop:\n  period_ms: 100\n  registration_budget_ms: 50\n  acquire_timeout_ms: 40\n"
      "actuator:\n  type: virtual\n  latency_s: 0.1\n  max_speed_mm_s: 40\n  max_speed_deg_s: 10\n" +
      motion_yaml;
  auto scene = parse_scene(text, "small-closed-loop.yaml", std::filesystem::current_path());
  EXPECT_TRUE(scene.ok()) << scene.status().message();
  return *scene;
}

struct LoopRun {
  LoopSummary summary;
  JournalContents journal;
};

class ClosedLoop : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { pool_ = new tracking::ThreadPool(2); }
  static void TearDownTestSuite() { delete pool_; }

  LoopRun run_loop(const std::string& motion_yaml, std::int64_t cycles, SimSessionOptions options = {},
                   const std::string& frames_yaml = kLightFieldFrames) {
    auto prepared = prepare_scene(small_scene(motion_yaml, frames_yaml), "", pool_);
    EXPECT_TRUE(prepared.ok()) << prepared.status().message();
    scene_ = std::make_unique<PreparedScene>(std::move(prepared).value());
    options.cycles = cycles;
    options.simulated_clock = true;
    options.light_field_dir = lf_dir_.path();
    options.journal = dir_.path() / "journal.lfj";
    auto session = SimSession::create(*scene_, options, pool_);
    EXPECT_TRUE(session.ok()) << session.status().message();
    LoopRun r;
    auto summary = (*session)->run();
    EXPECT_TRUE(summary.ok()) << summary.status().message();
    r.summary = *summary;
    auto journal = read_journal(options.journal);
    EXPECT_TRUE(journal.ok()) << journal.status().message();
    r.journal = *journal;
    return r;
  }

  static tracking::ThreadPool* pool_;
  test::TempDir dir_;
  static test::TempDir lf_dir_;
  std::unique_ptr<PreparedScene> scene_;
};
tracking::ThreadPool* ClosedLoop::pool_ = nullptr;
test::TempDir ClosedLoop::lf_dir_;

const char* kBreathing =
    "motion:\n  setup_error: {translation_mm: [3, -2, 2], rotation_deg: [1, -0.5, 1]}\n"
    "  drift: {translation_mm_per_s: [0.02, 0.01, -0.02]}\n"
    "  breathing: {amplitude_mm: [0.5, 1.5, 4.5], period_s: 4}\n";

TEST_F(ClosedLoop, TracksDriftAndBreathingWithoutAllocatingInThousandCycles) {
  SimSessionOptions options;
  options.allocation_count = &process_allocation_count;
  const LoopRun r = run_loop(kBreathing, 1010, options);
  const LoopSummary& s = r.summary;
  SCOPED_TRACE(to_json(s).dump());
  EXPECT_EQ(s.cycles, 1010);
  EXPECT_TRUE(s.aligned);
  EXPECT_EQ(s.states[std::size_t(TrackingState::kTrack)], 1010)
      << "aligned in the first cycle, tracked throughout";
  EXPECT_EQ(s.holds, 0);
  EXPECT_EQ(s.faults, 0);
  ASSERT_TRUE(s.residual_p95_mm.has_value());
  EXPECT_LT(*s.residual_p95_mm, 0.5) << "true residual after correction, breathing 4.5 mm";
  EXPECT_LT(*s.residual_mean_mm, 0.35);
  ASSERT_TRUE(s.allocations_per_cycle.has_value());
  EXPECT_GE(s.allocation_cycles, 1000);
  EXPECT_EQ(*s.allocations_per_cycle, 0.0) << "steady-state cycles allocate nothing";

  // The journal: one record per cycle, the alignment first, then applied corrections with beam.
  ASSERT_EQ(r.journal.records.size(), 1010u);
  EXPECT_EQ(r.journal.torn_tail_bytes, 0u);
  const JournalRecord& first = r.journal.records.front();
  EXPECT_EQ(first.previous_state, std::uint8_t(TrackingState::kAlign));
  EXPECT_EQ(first.state, std::uint8_t(TrackingState::kTrack));
  EXPECT_EQ(first.event, 1 + int(TrackingEvent::kAligned));
  EXPECT_EQ(first.command_sent, 1) << "the set-up move";
  EXPECT_NEAR(first.command[0], -3.0, 0.3);
  EXPECT_NEAR(first.command[2], -2.0, 0.3);
  int with_beam = 0;
  for (std::size_t i = 0; i < r.journal.records.size(); ++i) {
    const JournalRecord& rec = r.journal.records[i];
    EXPECT_EQ(rec.cycle, i);
    EXPECT_EQ(rec.frame_sequence[0], i);
    with_beam += rec.beam_permit;
    EXPECT_GE(rec.true_residual_mm, 0.0);
  }
  EXPECT_GT(with_beam, 1000);
}

TEST_F(ClosedLoop, SuddenShiftHoldsInOneCycleAndRecoversAfterResume) {
  const std::string motion =
      "motion:\n  breathing: {amplitude_mm: [0, 1, 2], period_s: 4}\n"
      "  shifts: [{time_s: 3.0, translation_mm: [0, 8, 0]}]\n";
  SimSessionOptions options;
  options.auto_resume_s = 1.0;  // the operator looks, then resumes
  const LoopRun r = run_loop(motion, 80, options, kRayCastFrames);
  const auto& records = r.journal.records;
  ASSERT_EQ(records.size(), 80u);
  // The frame of cycle 30 is the first to show the shift; that cycle holds.
  const JournalRecord& shifted = records[30];
  EXPECT_EQ(shifted.previous_state, std::uint8_t(TrackingState::kTrack));
  EXPECT_EQ(shifted.state, std::uint8_t(TrackingState::kHold));
  EXPECT_EQ(shifted.gate_reason, std::uint8_t(GateReason::kStepTooLarge));
  EXPECT_EQ(shifted.command_sent, 0);
  EXPECT_EQ(shifted.beam_permit, 0);
  std::size_t resumed = 0;
  for (std::size_t i = 31; i < records.size(); ++i) {
    if (records[i].state != std::uint8_t(TrackingState::kHold)) {
      resumed = i;
      break;
    }
    EXPECT_EQ(records[i].command_sent, 0) << "nothing moves in HOLD";
    EXPECT_EQ(records[i].beam_permit, 0);
  }
  ASSERT_GT(resumed, 0u) << "the operator resumed";
  EXPECT_EQ(records[resumed].event, 1 + int(TrackingEvent::kOperatorResume));
  EXPECT_EQ(records[resumed].state, std::uint8_t(TrackingState::kTrack));
  EXPECT_EQ(records[resumed].command_sent, 1) << "the approved move of about 8 mm";
  EXPECT_NEAR(records[resumed].command[1], -8.0, 1.0);
  EXPECT_GT(records[resumed].true_residual_mm, 5.0);
  bool recovered = false;
  for (std::size_t i = resumed; i <= resumed + 5 && i < records.size(); ++i)
    recovered = recovered || records[i].true_residual_mm < 0.5;
  EXPECT_TRUE(recovered) << "residual back under 0.5 mm within 5 cycles of the resume";
  EXPECT_EQ(r.summary.holds, 1);
  EXPECT_EQ(r.summary.faults, 0);
}

TEST_F(ClosedLoop, LostFramesSkipThenHoldThenFaultWithoutMoving) {
  SimSessionOptions options;
  options.frames.drop_from = 10;  // exposures 10.. never arrive
  options.frames.drop_to = 1000;
  const LoopRun r = run_loop(kBreathing, 30, options);
  const auto& records = r.journal.records;
  ASSERT_EQ(records.size(), 30u);
  EXPECT_EQ(records[10].gate_decision, std::uint8_t(GateDecision::kSkip));
  EXPECT_EQ(records[10].gate_reason, std::uint8_t(GateReason::kNoResult));
  EXPECT_EQ(records[11].gate_decision, std::uint8_t(GateDecision::kSkip));
  EXPECT_EQ(records[12].state, std::uint8_t(TrackingState::kHold)) << "the third failure in a row holds";
  EXPECT_EQ(records[19].state, std::uint8_t(TrackingState::kFault)) << "the tenth stops";
  for (std::size_t i = 10; i < records.size(); ++i) {
    EXPECT_EQ(records[i].command_sent, 0);
    EXPECT_EQ(records[i].beam_permit, 0);
  }
  EXPECT_EQ(r.summary.holds, 1);
  EXPECT_EQ(r.summary.faults, 1);
}

}  // namespace
}  // namespace lftrack::host
