// Archive and replay end to end: a simulated closed-loop run archives its frames (and the
// couch's read-back); replaying the archive through the same loop reproduces the run's
// registrations and decisions; bad frames in the archive become journaled statuses, and the
// replay ends with the sequence. Neither the archive nor the replay allocates in the cycle.

#include <gtest/gtest.h>

#include <fstream>

#include "lftrack/drivers/frame_files.hpp"

#include "lftrack/loop/allocation_counter.hpp"
#include "lftrack/records/loop_json.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "loop_fixture.hpp"

namespace lftrack::session {

using loop::GateDecision;
using loop::GateReason;
using loop::JournalRecord;
using loop::LoopSummary;
using loop::process_allocation_count;
using loop::TrackingState;

using records::to_json;
namespace {

class ArchiveAndReplay : public ClosedLoop {
 protected:
  // A 40-cycle run under breathing, archived.
  LoopRun record() {
    LoopSessionOptions options;
    options.simulator = sim_devices::room_simulator();
    options.archive = dir_.path() / "sequence";
    options.journal = dir_.path() / "recorded.lfj";
    options.allocation_count = &process_allocation_count;
    return run_loop(kBreathing, 40, options);
  }
  LoopRun replay() {
    LoopSessionOptions options;
    options.simulator = sim_devices::room_simulator();
    options.replay_sequence = dir_.path() / "sequence";
    options.journal = dir_.path() / "replayed.lfj";
    options.allocation_count = &process_allocation_count;
    return run_loop(kBreathing, 0, options);  // 0: to the end of the sequence
  }
};

TEST_F(ArchiveAndReplay, ReplayReproducesTheRecordedRegistrationsAndDecisions) {
  const LoopRun recorded = record();
  ASSERT_EQ(recorded.journal.records.size(), 40u);
  ASSERT_TRUE(recorded.summary.allocations_per_cycle.has_value());
  EXPECT_EQ(*recorded.summary.allocations_per_cycle, 0.0) << "archiving allocates nothing in the cycle";

  const LoopRun replayed = replay();
  const LoopSummary& s = replayed.summary;
  SCOPED_TRACE(to_json(s).dump());
  EXPECT_EQ(s.cycles, 40);
  EXPECT_EQ(s.ended, "end of the sequence");
  EXPECT_EQ(s.states[std::size_t(TrackingState::kTrack)], 40);
  EXPECT_FALSE(s.residual_mean_mm.has_value()) << "a replay knows no truth";
  ASSERT_TRUE(s.allocations_per_cycle.has_value());
  EXPECT_EQ(*s.allocations_per_cycle, 0.0) << "the replay's reader fills buffers made at open";
  ASSERT_EQ(replayed.journal.records.size(), 40u);
  double worst_mm = 0, worst_rad = 0;
  for (std::size_t i = 0; i < 40; ++i) {
    const JournalRecord& a = recorded.journal.records[i];
    const JournalRecord& b = replayed.journal.records[i];
    EXPECT_EQ(a.frame_sequence[0], b.frame_sequence[0]);
    EXPECT_EQ(a.gate_decision, b.gate_decision) << "cycle " << i;
    EXPECT_EQ(a.beam_withheld, b.beam_withheld) << "cycle " << i;
    for (int k = 0; k < 3; ++k) {
      worst_mm = std::max(worst_mm, std::abs(a.pose_delta[k] - b.pose_delta[k]));
      worst_rad = std::max(worst_rad, std::abs(a.pose_delta[3 + k] - b.pose_delta[3 + k]));
      worst_mm = std::max(worst_mm, std::abs(a.readback[k] - b.readback[k]));
    }
  }
  // The same frames and the same couch read-back (stored to 17 digits) give the same warm starts
  // and so the same registrations, to the last bit in practice. (A registration cut short by its
  // 50 ms wall-clock budget in one run and not the other would differ; these take about 10 ms.)
  EXPECT_LT(worst_mm, 1e-6);
  EXPECT_LT(worst_rad, 1e-8);
}

// A replay moves nothing and treats no one: its records say so (issue 50: the summary counted
// "corrections sent" to the recorded couch, and the journal had command_sent and beam_permit set
// where the recording had them).
void expect_nothing_sent_and_no_beam(const LoopRun& recorded, const LoopRun& replayed) {
  EXPECT_GT(recorded.summary.commands, 0) << "the recording moved its couch";
  std::int64_t beam_cycles = 0;
  for (const JournalRecord& r : recorded.journal.records) beam_cycles += r.beam_permit;
  EXPECT_GT(beam_cycles, 0) << "the recording permitted the beam";
  EXPECT_EQ(replayed.summary.commands, 0) << "nothing is sent to any actuator in a replay";
  EXPECT_EQ(replayed.summary.states[std::size_t(TrackingState::kTrack)], replayed.summary.cycles);
  ASSERT_EQ(replayed.journal.records.size(), recorded.journal.records.size());
  for (std::size_t i = 0; i < replayed.journal.records.size(); ++i) {
    const JournalRecord& r = replayed.journal.records[i];
    EXPECT_EQ(r.gate_decision, recorded.journal.records[i].gate_decision) << "the same decisions, cycle " << i;
    EXPECT_EQ(r.command_sent, 0) << "cycle " << i;
    for (double v : r.command) EXPECT_EQ(v, 0.0) << "cycle " << i;
    EXPECT_EQ(r.beam_permit, 0) << "cycle " << i;
  }
}

TEST_F(ArchiveAndReplay, AReplaySendsNothingAndPermitsNoBeam) {
  const LoopRun recorded = record();
  expect_nothing_sent_and_no_beam(recorded, replay());
}

// An archive without the couch's read-backs (a run that tracked and reported): the replay has no
// actuator at all, and still permits no beam.
TEST_F(ArchiveAndReplay, AReplayWithoutRecordedReadbacksPermitsNoBeam) {
  edit_scene_ = [](Scene& s) { s.actuator.type = "none"; };
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.archive = dir_.path() / "sequence";
  options.journal = dir_.path() / "recorded.lfj";
  // No set-up error: the patient stays within the beam's tolerance with nothing to move them.
  const LoopRun recorded = run_loop("motion:\n  breathing: {amplitude_mm: [0, 0.5, 1], period_s: 4}\n", 30, options);
  ASSERT_FALSE(std::filesystem::exists(dir_.path() / "sequence" / "actuator.csv"));
  std::int64_t beam_cycles = 0;
  for (const JournalRecord& r : recorded.journal.records) beam_cycles += r.beam_permit;
  EXPECT_GT(beam_cycles, 0) << "the recording permitted the beam";
  const LoopRun replayed = replay();
  EXPECT_EQ(replayed.summary.cycles, 30);
  for (std::size_t i = 0; i < replayed.journal.records.size(); ++i)
    EXPECT_EQ(replayed.journal.records[i].beam_permit, 0) << "cycle " << i;
}

// A simulated frame covers the whole detector, as a real panel's does (issue 51): every pixel
// outside the ROI window is exposed, at the level of the window's pixels next to it.
TEST_F(ArchiveAndReplay, TheArchivedFramesCoverTheWholeDetector) {
  record();
  for (std::size_t v = 0; v < scene_->scene.detectors.size(); ++v) {
    const auto& view = scene_->scene.detectors[v].view;
    tracking::Image<std::uint16_t> frame(view.rows, view.cols);
    const std::string name = std::string("000020-") + view.name + ".tif";
    ASSERT_TRUE(drivers::read_frame_file((dir_.path() / "sequence" / "frames" / name).c_str(), frame.view()).ok());
    const tracking::PixelWindow& w = scene_->roi_windows[v];
    ASSERT_GT(w.row0, 4) << "the window leaves room around it";
    int unexposed = 0;
    for (int r = 0; r < view.rows; ++r)
      for (int c = 0; c < view.cols; ++c) unexposed += frame.at(r, c) == 0 ? 1 : 0;
    EXPECT_EQ(unexposed, 0) << "view " << view.name;
    // The rows just above the window and its own first rows, over the window's columns.
    double outside = 0, inside = 0;
    for (int c = w.col0; c < w.col0 + w.cols; ++c)
      for (int k = 1; k <= 3; ++k) {
        outside += frame.at(w.row0 - k, c);
        inside += frame.at(w.row0 + k - 1, c);
      }
    EXPECT_NEAR(outside / inside, 1.0, 0.1) << "no step at the window's edge, view " << view.name;
  }
}

TEST_F(ArchiveAndReplay, BadFramesInTheArchiveAreJournaledStatusesNotCrashes) {
  record();
  const auto frames = dir_.path() / "sequence" / "frames";
  std::filesystem::remove(frames / "000010-A.tif");
  std::ofstream(frames / "000020-B.tif", std::ios::trunc) << "not a TIFF";
  const LoopRun r = replay();
  const auto& records = r.journal.records;
  ASSERT_EQ(records.size(), 40u);
  for (std::size_t i : {10u, 20u}) {
    EXPECT_EQ(records[i].gate_decision, std::uint8_t(GateDecision::kSkip)) << i;
    EXPECT_EQ(records[i].gate_reason, std::uint8_t(GateReason::kNoFrames)) << i;
    EXPECT_EQ(records[i].command_sent, 0) << i;
    EXPECT_EQ(records[i].beam_permit, 0) << i;
  }
  EXPECT_EQ(r.summary.states[std::size_t(TrackingState::kTrack)], 40) << "single bad pairs skip, never hold";
}

// The image-quality gate on frames a detector could really deliver: each bad frame's cycle is
// skipped with reason "image quality"; nothing is registered, sent or beamed from it.
TEST_F(ArchiveAndReplay, SaturatedBlankUniformAndDeadPixelFramesAreSkippedByTheImageQualityGate) {
  record();
  const auto frames = dir_.path() / "sequence" / "frames";
  tracking::Image<std::uint16_t> image(scene_->scene.detectors[0].view.rows,
                                       scene_->scene.detectors[0].view.cols);
  const auto write = [&](const char* name) {
    ASSERT_TRUE(drivers::write_frame_file((frames / name).c_str(), image.view()).ok());
  };
  const int full_scale = (1 << scene_->scene.detectors[0].bits) - 1;
  std::fill(image.pixels().begin(), image.pixels().end(), static_cast<std::uint16_t>(full_scale));
  write("000008-A.tif");  // saturated
  std::fill(image.pixels().begin(), image.pixels().end(), std::uint16_t(0));
  write("000012-B.tif");  // blank
  std::fill(image.pixels().begin(), image.pixels().end(), std::uint16_t(2000));
  write("000016-A.tif");  // uniform
  ASSERT_TRUE(drivers::read_frame_file((frames / "000020-A.tif").c_str(), image.view()).ok());
  for (int r = 0; r < image.rows(); ++r)
    for (int c = 0; c < image.cols(); c += 4) image.at(r, c) = 0;  // a quarter of the panel dead
  write("000020-A.tif");
  const LoopRun r = replay();
  const auto& records = r.journal.records;
  ASSERT_EQ(records.size(), 40u);
  for (std::size_t i : {8u, 12u, 16u, 20u}) {
    EXPECT_EQ(records[i].gate_decision, std::uint8_t(GateDecision::kSkip)) << i;
    EXPECT_EQ(records[i].gate_reason, std::uint8_t(GateReason::kImageQuality)) << i;
    EXPECT_EQ(records[i].command_sent, 0) << i;
    EXPECT_EQ(records[i].beam_permit, 0) << i;
    EXPECT_EQ(records[i].evaluations, 0u) << "not registered, cycle " << i;
  }
  EXPECT_EQ(r.summary.decisions[std::size_t(GateDecision::kSkip)], 4) << "every other frame passes";
}

TEST_F(ArchiveAndReplay, AMissingOrBrokenSequenceIsRefusedAtStart) {
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.replay_sequence = dir_.path() / "nothing-here";
  auto prepared = prepare_scene(small_scene(kBreathing, kLightFieldFrames), "", pool_);
  ASSERT_TRUE(prepared.ok());
  options.light_field_dir = shared_light_field_dir(*prepared);
  auto session = LoopSession::create(*prepared, options, pool_);
  ASSERT_FALSE(session.ok());
  EXPECT_NE(session.status().message().find("no such sequence directory"), std::string::npos);
  std::filesystem::create_directories(options.replay_sequence);
  std::ofstream(options.replay_sequence / "index.csv")
      << "pair,detector,sequence,timestamp_ns,file\n0,A,x,1,f.tif\n";
  session = LoopSession::create(*prepared, options, pool_);
  ASSERT_FALSE(session.ok());
  EXPECT_NE(session.status().message().find("index.csv:2: sequence 'x'"), std::string::npos)
      << session.status().message();
}

}  // namespace
}  // namespace lftrack::session
