// The loop on its own (lftrack::loop, no scene, no simulator): whatever a cycle throws, the
// actuator is held and the beam permit dropped before the exception reaches the caller.

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <new>
#include <stdexcept>
#include <thread>
#include <utility>
#include <vector>

#include "lftrack/drivers/forwarding_actuator.hpp"
#include "lftrack/loop/cycle_schedule.hpp"
#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/tracking_loop.hpp"
#include "lftrack/records/journal_reader.hpp"
#include "loop_doubles.hpp"
#include "test_data.hpp"

namespace lftrack::loop {

using records::read_journal;
namespace {

using tracking::PixelWindow;
using tracking::XrayView;

// A smooth pattern that moves with the pose: enough for a Registration to be built.
class PatternRenderer final : public tracking::DrrRenderer {
 public:
  explicit PatternRenderer(std::chrono::microseconds per_render = {}) : per_render_(per_render) {}
  std::string_view name() const override { return "pattern"; }

 protected:
  Status do_render(const tracking::Pose& T, const XrayView&, const PixelWindow& window,
                   tracking::ImageView<float> out, tracking::RenderExtras* extras) const override {
    if (per_render_.count() > 0) std::this_thread::sleep_for(per_render_);  // a slow host
    for (int r = 0; r < window.rows; ++r)
      for (int c = 0; c < window.cols; ++c) {
        out.at(r, c) = static_cast<float>(1.0 + std::sin(0.2 * c + T.translation().x()) * std::cos(0.15 * r));
        if (!extras->valid.empty()) extras->valid.at(r, c) = 1;
      }
    return {};
  }

 private:
  std::chrono::microseconds per_render_;
};

// Frames of a fixed pattern (anatomy enough for the image-quality gate); throws what it is told to
// on the acquisition numbered `throw_at`.
class ThrowingFrames final : public drivers::FrameSource {
 public:
  explicit ThrowingFrames(int throw_at, bool bad_alloc) : throw_at_(throw_at), bad_alloc_(bad_alloc) {}
  Status open(drivers::FramePair* pair) override {
    test::open_pattern_pair(pair);
    return {};
  }
  drivers::DeviceStatus acquire(drivers::FramePair* pair, drivers::Deadline) override {
    if (acquisitions_++ == throw_at_) {
      if (bad_alloc_) throw std::bad_alloc();
      throw std::runtime_error("frame source broke");
    }
    for (auto& f : pair->frames) f.timestamp_ns = monotonic_now_ns();
    return drivers::DeviceStatus::kOk;
  }
  void close() override {}

 private:
  int throw_at_;
  bool bad_alloc_;
  int acquisitions_ = 0;
};

// Records what the loop asked of it; its read-back (and then its hold) can be made to throw.
class RecordingActuator final : public drivers::Actuator {
 public:
  Status open() override { return {}; }
  drivers::DeviceStatus command(const tracking::Vector6d&, drivers::Deadline) override {
    ++commands;
    return drivers::DeviceStatus::kOk;
  }
  drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline) override {
    if (readback_throws) throw std::runtime_error("read-back broke");
    *state = {};
    return drivers::DeviceStatus::kOk;
  }
  void hold() override {
    ++holds;
    if (hold_throws) throw std::runtime_error("hold broke too");
  }
  void set_beam_permit(bool permit) override { beam_permit = permit; }
  void close() override {}

  bool readback_throws = false, hold_throws = false;
  int holds = 0, commands = 0;
  bool beam_permit = true;  // as if an earlier cycle had allowed the beam
};

struct LoopUnderTest {
  std::unique_ptr<tracking::Registration> registration;
  std::unique_ptr<PlannedRegistration> planned;
  std::unique_ptr<TrackingLoop> loop;
};

struct LoopOptions {
  JournalWriter* journal = nullptr;
  OperatorInput* operator_input = nullptr;
  std::chrono::microseconds per_render{0};  // each render sleeps this long: a slow or loaded host
  double max_frame_age_ms = 150;
  std::int64_t cycles = 20;
};

// The loop on `frames` and `actuator` (with t->registration made for it), or why create() refused.
Result<std::unique_ptr<TrackingLoop>> create_loop(drivers::FrameSource* frames, drivers::Actuator* actuator,
                                                  LoopUnderTest* t, const LoopOptions& o = {}) {
  LoopParts parts = test::pattern_loop_parts();
  EXPECT_EQ(parts.geometry.views.size(), 2u);
  tracking::RegistrationSetup setup;
  for (std::size_t v = 0; v < parts.geometry.views.size(); ++v)
    setup.views.push_back({parts.geometry.views[v], parts.geometry.roi_windows[v], {}});
  auto registration = tracking::Registration::create(std::make_shared<PatternRenderer>(o.per_render), setup, nullptr);
  if (!registration.ok()) return registration.status();
  t->registration = std::move(registration).value();
  t->planned = std::make_unique<PlannedRegistration>(t->registration.get());
  parts.registration = t->planned.get();
  parts.frames = frames;
  parts.actuator = actuator;
  parts.journal = o.journal;
  parts.operator_input = o.operator_input;
  LoopSettings settings;
  settings.cycles = o.cycles;
  settings.limits.max_frame_age_ms = o.max_frame_age_ms;
  settings.simulated_clock = true;
  return TrackingLoop::create(parts, settings);
}

LoopUnderTest make_loop(drivers::FrameSource* frames, drivers::Actuator* actuator, const LoopOptions& o = {}) {
  LoopUnderTest t;
  auto loop = create_loop(frames, actuator, &t, o);
  EXPECT_TRUE(loop.ok()) << loop.status().message();
  if (loop.ok()) t.loop = std::move(loop).value();
  return t;
}

TEST(TrackingLoop, AnAllocationFailureInACycleHoldsTheActuatorAndDropsTheBeamBeforeItPropagates) {
  // The first acquisition throws: no cycle has held anything before it.
  ThrowingFrames frames(/*throw_at=*/0, /*bad_alloc=*/true);
  RecordingActuator actuator;
  LoopUnderTest t = make_loop(&frames, &actuator);
  ASSERT_TRUE(t.loop);
  actuator.beam_permit = true;
  EXPECT_THROW((void)t.loop->run(), std::bad_alloc);
  EXPECT_EQ(actuator.holds, 1) << "the actuator was held on the way out";
  EXPECT_FALSE(actuator.beam_permit) << "the beam permit was dropped";
}

TEST(TrackingLoop, AnActuatorThatThrowsInTheCycleAndOnHoldStillLosesTheBeamPermit) {
  ThrowingFrames frames(/*throw_at=*/-1, /*bad_alloc=*/false);
  RecordingActuator actuator;
  actuator.readback_throws = true;
  actuator.hold_throws = true;
  LoopUnderTest t = make_loop(&frames, &actuator);
  ASSERT_TRUE(t.loop);
  actuator.beam_permit = true;
  EXPECT_THROW((void)t.loop->run(), std::runtime_error);
  EXPECT_GE(actuator.holds, 1) << "a hold was attempted";
  EXPECT_FALSE(actuator.beam_permit) << "a hold that throws does not keep the beam on";
  EXPECT_EQ(actuator.commands, 0);
}

// A run of the loop on `frames` and `actuator` with a journal: its summary and the records read
// back (empty where the run or the journal failed, which the expectations inside say).
struct JournaledRun {
  LoopSummary summary;
  std::vector<JournalRecord> records;
};

JournaledRun run_journaled(drivers::FrameSource* frames, drivers::Actuator* actuator, LoopOptions o) {
  JournaledRun out;
  test::TempDir dir;
  auto journal = JournalWriter::open(dir.path() / "run.lfj");
  EXPECT_TRUE(journal.ok()) << journal.status().message();
  if (!journal.ok()) return out;
  o.journal = journal->get();
  LoopUnderTest t = make_loop(frames, actuator, o);
  if (!t.loop) return out;
  auto summary = t.loop->run();
  EXPECT_TRUE(summary.ok()) << summary.status().message();
  EXPECT_TRUE((*journal)->close().ok());
  if (!summary.ok()) return out;
  out.summary = *summary;
  auto read = read_journal(dir.path() / "run.lfj");
  EXPECT_TRUE(read.ok()) << read.status().message();
  if (read.ok()) out.records = read->records;
  return out;
}

// A couch that takes each correction as its new target and whose link drops on the read-backs
// numbered in `drops` (0: the loop's first, before its first cycle): that read-back and the next
// fail, and the couch comes back held where it stood, short of the last command (a couch stopped
// mid-move) and somewhere new each time.
class CouchThatDropsItsLink final : public drivers::Actuator {
 public:
  explicit CouchThatDropsItsLink(std::vector<int> drops) : drops_(std::move(drops)) {}
  Status open() override { return {}; }
  drivers::DeviceStatus command(const tracking::Vector6d& correction, drivers::Deadline) override {
    target_ += correction;
    return drivers::DeviceStatus::kOk;
  }
  drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline) override {
    const int n = readbacks_++;
    for (int d : drops_) {
      if (n == d || n == d + 1) return drivers::DeviceStatus::kDisconnected;
      if (n == d + 2) target_ += (tracking::Vector6d() << 2.5, -1.5, 0.5, 0, 0, 0).finished();
    }
    *state = {};
    state->target = state->position = target_;
    return drivers::DeviceStatus::kOk;
  }
  void hold() override {}
  void set_beam_permit(bool) override {}
  void close() override {}

 private:
  std::vector<int> drops_;
  int readbacks_ = 0;
  tracking::Vector6d target_ = tracking::Vector6d::Zero();
};

// A link dropped on a read-back holds the loop (HOLD: the read-back failed), and the couch that
// comes back held short of the last command is where the loop now holds it, not a disagreement
// with a command (read-back mismatch) that counts the hold up into a FAULT: ClosedLoop's
// DroppedConnection case did so whenever the couch was still moving at the drop (a loaded CI
// host). The second drop comes while held. (This harness's pattern does not track for long: its
// own failures reach fault_after_failures after ten cycles, so the run is shorter than that.)
TEST(TrackingLoop, ACouchHeldWhereItStoodAfterADroppedLinkIsHeldThereNotAMismatch) {
  ThrowingFrames frames(/*throw_at=*/-1, /*bad_alloc=*/false);
  // Read-backs: 0 before the loop, 1 in cycle 0, 2 in cycle 1 (TRACK, dropped), 3 on the hold.
  CouchThatDropsItsLink couch({2, 6});
  LoopOptions o;
  o.cycles = 9;
  const JournaledRun run = run_journaled(&frames, &couch, o);
  EXPECT_EQ(run.summary.faults, 0);
  EXPECT_EQ(run.summary.holds, 1);
  const std::vector<JournalRecord>& records = run.records;
  ASSERT_EQ(records.size(), 9u);
  EXPECT_EQ(records[0].state, std::uint8_t(TrackingState::kTrack));
  EXPECT_EQ(records[1].state, std::uint8_t(TrackingState::kHold));
  EXPECT_EQ(records[1].gate_reason, std::uint8_t(GateReason::kActuatorFault));
  int relinked = 0;
  for (std::size_t i = 1; i < records.size(); ++i) {
    const JournalRecord& r = records[i];
    EXPECT_EQ(r.state, std::uint8_t(TrackingState::kHold)) << "cycle " << i;
    EXPECT_NE(r.gate_reason, std::uint8_t(GateReason::kReadbackMismatch)) << "cycle " << i;
    EXPECT_EQ(r.command_sent, 0) << "held: nothing sent, cycle " << i;
    relinked += r.gate_reason != std::uint8_t(GateReason::kActuatorFault) && r.readback[0] != 0;
  }
  EXPECT_GT(relinked, 0) << "the couch came back and was read";
}

// An operator who resumes a HOLD in the cycle numbered `at` (a scripted input for the loop alone).
class ResumesAtCycle final : public OperatorInput {
 public:
  explicit ResumesAtCycle(std::int64_t at) : at_(at) {}
  void poll(const OperatorView& view, OperatorPoll* out) override {
    if (view.cycle == at_ && view.state == TrackingState::kHold) out->accept(OperatorCommand::kResume);
  }

 private:
  std::int64_t at_;
};

// The operator resumes in the very cycle the couch comes back, held somewhere the loop has not
// read: the decision was taken without that target, so the read-back is compared as always, holds
// (read-back mismatch) and moves nothing; that hold's read-back is the target for the next
// decision (review of the fix above: adopting it in the resume's cycle would have sent a command
// from a target nobody had seen, with the step limit waived).
TEST(TrackingLoop, AResumeBeforeTheHeldCouchWasReadMovesNothing) {
  ThrowingFrames frames(/*throw_at=*/-1, /*bad_alloc=*/false);
  // Read-backs: 0 before the loop, 1 in cycle 0, 2 in cycle 1 (dropped), 3 on the hold (fails),
  // 4 in cycle 2: the couch is back, moved, in the cycle of the resume.
  CouchThatDropsItsLink couch({2});
  ResumesAtCycle resume(2);
  LoopOptions o;
  o.operator_input = &resume;
  o.cycles = 5;
  const std::vector<JournalRecord> records = run_journaled(&frames, &couch, o).records;
  ASSERT_EQ(records.size(), 5u);
  EXPECT_EQ(records[1].state, std::uint8_t(TrackingState::kHold));
  const JournalRecord& resumed = records[2];
  EXPECT_NE(resumed.operator_command, 0) << "the resume was taken";
  EXPECT_EQ(resumed.state, std::uint8_t(TrackingState::kHold));
  EXPECT_EQ(resumed.gate_reason, std::uint8_t(GateReason::kReadbackMismatch));
  EXPECT_EQ(resumed.command_sent, 0) << "nothing sent on a target the operator had not seen";
  EXPECT_EQ(resumed.beam_permit, 0);
  for (std::size_t i = 3; i < records.size(); ++i) {
    EXPECT_EQ(records[i].command_sent, 0) << "held again, cycle " << i;
    EXPECT_NE(records[i].gate_reason, std::uint8_t(GateReason::kReadbackMismatch))
        << "the second hold read the target, cycle " << i;
  }
}

// An operator input whose every poll brings refusals of three reasons.
class RefusedSeveralWays final : public OperatorInput {
 public:
  void poll(const OperatorView&, OperatorPoll* out) override {
    out->refuse(OperatorRefusal::kBadToken, 15);
    out->refuse(OperatorRefusal::kReplayed);
    out->refuse(OperatorRefusal::kNotApplicable, 2);
  }
};

// Every refusal of a cycle reaches its journal record and the run's summary by reason (an outside
// probe's 15 token failures never appeared: each cycle kept only its last reason).
TEST(TrackingLoop, EveryRefusalOfACycleIsJournaledByReason) {
  ThrowingFrames frames(/*throw_at=*/-1, /*bad_alloc=*/false);
  RefusedSeveralWays refusing;
  LoopOptions o;
  o.operator_input = &refusing;
  const JournaledRun run = run_journaled(&frames, nullptr, o);
  const LoopSummary& summary = run.summary;
  EXPECT_EQ(summary.operator_refused, 18 * summary.cycles);
  EXPECT_EQ(summary.operator_refused_by_reason[std::size_t(OperatorRefusal::kBadToken)], 15 * summary.cycles);
  EXPECT_EQ(summary.operator_refused_by_reason[std::size_t(OperatorRefusal::kReplayed)], summary.cycles);
  ASSERT_FALSE(run.records.empty());
  for (const JournalRecord& r : run.records) {
    EXPECT_EQ(r.operator_refused, 18);
    EXPECT_EQ(r.operator_first_refusal, std::uint8_t(OperatorRefusal::kBadToken));
    EXPECT_EQ(r.operator_refusal, std::uint8_t(OperatorRefusal::kNotApplicable));
    EXPECT_EQ(r.operator_refused_by_reason[std::size_t(OperatorRefusal::kBadToken)], 15);
    EXPECT_EQ(r.operator_refused_by_reason[std::size_t(OperatorRefusal::kReplayed)], 1);
    EXPECT_EQ(r.operator_refused_by_reason[std::size_t(OperatorRefusal::kNotApplicable)], 2);
  }
}

// On the simulated clock a cycle's work takes no time: however slow the host, a frame is as old at
// the decision as the clock says, and a run repeats from its seed. (The host's computing time
// used to count: a loaded run's frames went "stale" where an idle run's did not, and two runs of
// one seed diverged: ClosedLoop.TwoRunsOfOneSeedOnTheSimulatedClockAreTheSameBitForBit.)
TEST(TrackingLoop, OnTheSimulatedClockTheHostsComputingTimeNeverAgesAFrame) {
  ThrowingFrames frames(/*throw_at=*/-1, /*bad_alloc=*/false);
  LoopOptions o;
  o.per_render = std::chrono::microseconds(2000);  // a registration takes tens of milliseconds
  o.max_frame_age_ms = 5;
  o.cycles = 4;
  const JournaledRun run = run_journaled(&frames, nullptr, o);
  EXPECT_GT(run.summary.registration_p50_ms, 5.0) << "each registration took longer than the frame age limit";
  ASSERT_EQ(run.records.size(), 4u);
  for (const JournalRecord& r : run.records) {
    EXPECT_NE(r.gate_reason, std::uint8_t(GateReason::kStaleFrame)) << "cycle " << r.cycle;
    EXPECT_GT(r.evaluations, 0u) << "cycle " << r.cycle;
  }
}

// Frames from an archive (live() false) show a patient who is no longer there: the loop refuses
// to drive an actuator that moves a patient by them (issue 50), and accepts one that does not.
TEST(TrackingLoop, ArchivedFramesCannotDriveAnActuatorThatMovesAPatient) {
  class ArchivedFrames final : public drivers::FrameSource {
   public:
    Status open(drivers::FramePair* pair) override { return frames_.open(pair); }
    drivers::DeviceStatus acquire(drivers::FramePair* pair, drivers::Deadline deadline) override {
      return frames_.acquire(pair, deadline);
    }
    bool live() const override { return false; }
    void close() override {}
   private:
    ThrowingFrames frames_{-1, false};
  };
  class RecordedReadbacks final : public drivers::ForwardingActuator {
   public:
    using ForwardingActuator::ForwardingActuator;
    bool moves_patient() const override { return false; }
  };
  ArchivedFrames frames;
  RecordingActuator couch;
  LoopUnderTest t;
  auto refused = create_loop(&frames, &couch, &t);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("archived frames cannot move a patient"), std::string::npos)
      << refused.status().message();
  RecordedReadbacks recorded(&couch);
  LoopUnderTest accepted = make_loop(&frames, &recorded);
  EXPECT_TRUE(accepted.loop);
}

}  // namespace
}  // namespace lftrack::loop
