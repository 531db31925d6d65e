// The loop's state machine against a scripted registration (loop_registration.hpp): ALIGN,
// TRACK, HOLD and FAULT, the operator's commands, overruns and refused commands, each in a few
// milliseconds on the simulated clock, with no image worth registering. The scripted
// registration "sees" the patient through the couch as the real one does: the pose it reports
// is the couch's motion applied to the patient's scripted offset from the plan.

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <vector>

#include "lftrack/loop/loop_registration.hpp"
#include "lftrack/loop/tracking_loop.hpp"
#include "loop_doubles.hpp"

namespace lftrack::loop {
namespace {

using tracking::Pose;
using tracking::PoseDelta;
using tracking::Vector6d;

Pose motion(const Vector6d& d) { return tracking::apply_delta(Pose::Identity(), PoseDelta::from_vector(d), {0, 0, 0}); }

Vector6d translation(double x, double y, double z) { return (Vector6d() << x, y, z, 0, 0, 0).finished(); }

// A couch whose position is its target at once: each correction adds to it. It can be told to
// refuse the commands numbered in `refuse` (DeviceStatus::kRefused: it knows of a fault, nothing
// moved), or to leave those in `time_out` unanswered (kTimeout: they may have moved). Every
// command it takes is kept.
class InstantCouch final : public drivers::Actuator {
 public:
  Status open() override { return {}; }
  drivers::DeviceStatus command(const Vector6d& correction, drivers::Deadline) override {
    const int n = commands_seen++;
    for (int r : refuse)
      if (r == n) return drivers::DeviceStatus::kRefused;
    for (int r : time_out)
      if (r == n) return drivers::DeviceStatus::kTimeout;
    commands.push_back(correction);
    target += correction;
    return drivers::DeviceStatus::kOk;
  }
  drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline) override {
    *state = {};
    state->target = state->position = target;
    return drivers::DeviceStatus::kOk;
  }
  void hold() override { ++holds; }
  void set_beam_permit(bool permit) override { beam_permit = permit; }
  void close() override {}

  Vector6d target = Vector6d::Zero();
  std::vector<Vector6d> commands;  // those taken
  std::vector<int> refuse;         // command numbers (from 0) refused
  std::vector<int> time_out;       // command numbers (from 0) left unanswered
  int commands_seen = 0, holds = 0;
  bool beam_permit = false;
};

// One registration's scripted answer.
struct Answer {
  Vector6d patient = Vector6d::Zero();  // the patient's offset from the plan, on the couch
  bool fails = false;                   // run() returns an error
  bool non_finite = false;              // run() succeeds with a NaN in the pose
  double similarity = 0.9;              // every view's, at the result
};

// Answers run number n (from 0) with script(n); what the loop asked is kept.
class ScriptedRegistration final : public LoopRegistration {
 public:
  ScriptedRegistration(const InstantCouch* couch, std::function<Answer(int)> script)
      : couch_(couch), script_(std::move(script)) {}
  Status prepare(const tracking::RegistrationPlan&, const tracking::RegistrationPlan&) override {
    ++prepared;
    return prepare_error;
  }
  Status set_frames(const std::vector<tracking::ImageView<const float>>& frames,
                    const std::vector<tracking::ImageView<const unsigned char>>&) override {
    frames_set += !frames.empty();
    return {};
  }
  Status run(const Pose&, RegistrationStage stage, double, tracking::RegistrationResult* result) override {
    const Answer a = script_(static_cast<int>(stages.size()));
    stages.push_back(stage);
    if (a.fails) return internal_error("scripted failure");
    const Vector6d couch = couch_ != nullptr ? couch_->target : Vector6d::Zero();
    result->T_room_from_ct = motion(couch) * motion(a.patient);
    if (a.non_finite) result->T_room_from_ct.translation().x() = std::numeric_limits<double>::quiet_NaN();
    result->view_similarity.assign(2, a.similarity);
    result->evaluations = 1;
    result->elapsed_ms = 1;
    result->stop = tracking::OptimizerStop::kConverged;
    return {};
  }

  Status prepare_error;
  int prepared = 0, frames_set = 0;
  std::vector<RegistrationStage> stages;

 private:
  const InstantCouch* couch_;
  std::function<Answer(int)> script_;
};

// The operator's commands by cycle number, given as they come (the loop alone judges them here).
class CommandsAtCycles final : public OperatorInput {
 public:
  explicit CommandsAtCycles(std::map<std::int64_t, OperatorCommand> at) : at_(std::move(at)) {}
  void poll(const OperatorView& view, OperatorPoll* out) override {
    auto it = at_.find(view.cycle);
    if (it != at_.end()) out->accept(it->second);
  }

 private:
  std::map<std::int64_t, OperatorCommand> at_;
};

// Every cycle's record, and host stalls by cycle (ns).
class Records final : public CycleObserver {
 public:
  void on_cycle(const JournalRecord& record) override { all.push_back(record); }
  std::int64_t simulated_stall_ns(std::int64_t cycle) override {
    auto it = stall_ns.find(cycle);
    return it == stall_ns.end() ? 0 : it->second;
  }
  std::vector<JournalRecord> all;
  std::map<std::int64_t, std::int64_t> stall_ns;
};

struct Harness {
  test::PatternFrames frames;
  InstantCouch couch;
  Records records;
  std::unique_ptr<ScriptedRegistration> registration;
  OperatorInput* operator_input = nullptr;
  LoopSettings settings;

  explicit Harness(std::function<Answer(int)> script) {
    registration = std::make_unique<ScriptedRegistration>(&couch, std::move(script));
    settings.simulated_clock = true;
    settings.cycles = 20;
    settings.loop.prediction_cycles = 0;  // each command cancels the newest offset exactly
  }
  Result<std::unique_ptr<TrackingLoop>> create() {
    LoopParts parts = test::pattern_loop_parts();
    parts.registration = registration.get();
    parts.frames = &frames;
    parts.actuator = &couch;
    parts.operator_input = operator_input;
    parts.observer = &records;
    return TrackingLoop::create(parts, settings);
  }
  LoopSummary run() {
    auto loop = create();
    EXPECT_TRUE(loop.ok()) << loop.status().message();
    if (!loop.ok()) return {};
    auto summary = (*loop)->run();
    EXPECT_TRUE(summary.ok()) << summary.status().message();
    return summary.ok() ? *summary : LoopSummary{};
  }
  TrackingState state(std::size_t cycle) const { return static_cast<TrackingState>(records.all.at(cycle).state); }
};

Answer still_at(const Vector6d& patient) { return {patient, false, false, 0.9}; }

TEST(LoopStates, AlignsThenTracksAndTheSetUpMoveCancelsThePatientsOffset) {
  const Vector6d offset = translation(1.5, -1.0, 0.5);
  Harness h([&](int) { return still_at(offset); });
  const LoopSummary s = h.run();
  ASSERT_EQ(h.records.all.size(), 20u);
  EXPECT_EQ(h.registration->prepared, 1);
  EXPECT_EQ(h.registration->frames_set, 20);
  ASSERT_EQ(h.registration->stages.size(), 20u);
  EXPECT_EQ(h.registration->stages[0], RegistrationStage::kAlign);
  for (std::size_t i = 1; i < h.registration->stages.size(); ++i)
    EXPECT_EQ(h.registration->stages[i], RegistrationStage::kTrack) << "run " << i;
  EXPECT_TRUE(s.aligned);
  EXPECT_EQ(h.state(0), TrackingState::kTrack) << "aligned once the set-up move was taken";
  ASSERT_EQ(h.couch.commands.size(), 1u) << "a patient who keeps still needs only the set-up move";
  EXPECT_LT((h.couch.commands[0] + offset).norm(), 1e-9);
  EXPECT_EQ(h.records.all[0].beam_permit, 0) << "no beam in the set-up move's cycle";
  for (std::size_t i = 2; i < h.records.all.size(); ++i) {
    EXPECT_EQ(h.state(i), TrackingState::kTrack) << "cycle " << i;
    EXPECT_EQ(h.records.all[i].beam_permit, 1) << "on the plan, the beam is on: cycle " << i;
  }
  EXPECT_FALSE(h.couch.beam_permit) << "dropped at the run's end";
  EXPECT_EQ(s.holds, 0);
}

TEST(LoopStates, APatientWhoDriftsIsFollowedCycleByCycle) {
  // 0.3 mm a cycle along x after the alignment: each cycle's command cancels the newest offset.
  Harness h([](int n) { return still_at(translation(0.3 * n, 0, 0)); });
  (void)h.run();
  // The patient is on the plan at the alignment (no set-up move), then drifts: a command each cycle.
  ASSERT_EQ(h.couch.commands.size(), 19u) << "one command in each of the 19 cycles after the alignment";
  for (std::size_t i = 0; i < h.couch.commands.size(); ++i)
    EXPECT_LT((h.couch.commands[i] - translation(-0.3, 0, 0)).norm(), 1e-9) << "command " << i;
  EXPECT_LT((h.couch.target - translation(-0.3 * 19, 0, 0)).norm(), 1e-9);
}

TEST(LoopStates, FailedRegistrationsSkipThenHoldAndMoveNothing) {
  Harness h([](int n) {
    Answer a = still_at(translation(1, 0, 0));
    a.fails = n >= 5;
    return a;
  });
  h.settings.cycles = 9;
  const LoopSummary s = h.run();
  ASSERT_EQ(h.records.all.size(), 9u);
  EXPECT_EQ(h.state(5), TrackingState::kTrack) << "one failure skips the cycle";
  EXPECT_EQ(h.state(6), TrackingState::kTrack);
  EXPECT_EQ(h.state(7), TrackingState::kHold) << "the third in a row holds (hold_after_failures)";
  for (std::size_t i = 5; i < 9; ++i) {
    EXPECT_EQ(h.records.all[i].command_sent, 0) << "cycle " << i;
    EXPECT_EQ(h.records.all[i].beam_permit, 0) << "no beam without a registration: cycle " << i;
  }
  EXPECT_EQ(h.couch.commands.size(), 1u);
  EXPECT_EQ(h.couch.holds, 2) << "held on entering HOLD and at the run's end";
  EXPECT_EQ(s.holds, 1);
  EXPECT_EQ(s.faults, 0);
}

TEST(LoopStates, ANonFinitePoseIsNoResultAndNeverReachesTheCouch) {
  Harness h([](int n) {
    Answer a = still_at(translation(0.2 * n, 0, 0));
    a.non_finite = n == 4 || n == 9;
    return a;
  });
  (void)h.run();
  for (const Vector6d& c : h.couch.commands) EXPECT_TRUE(c.allFinite());
  EXPECT_EQ(h.records.all.at(4).command_sent, 0);
  EXPECT_EQ(h.records.all.at(9).command_sent, 0);
  EXPECT_EQ(h.records.all.at(4).gate_reason, std::uint8_t(GateReason::kNoResult));
  EXPECT_EQ(h.state(19), TrackingState::kTrack) << "single failures only skip";
}

TEST(LoopStates, AStepTooLargeHoldsAndTheOperatorsResumeMakesIt) {
  // The patient slides 3 mm at run 5 (over the 2 mm step limit), and keeps still there.
  Harness h([](int n) { return still_at(translation(n >= 5 ? 3.5 : 0.5, 0, 0)); });
  CommandsAtCycles operator_input({{7, OperatorCommand::kResume}});
  h.operator_input = &operator_input;
  h.settings.cycles = 12;
  (void)h.run();
  EXPECT_EQ(h.state(5), TrackingState::kHold);
  EXPECT_EQ(h.records.all[5].gate_reason, std::uint8_t(GateReason::kStepTooLarge));
  EXPECT_EQ(h.records.all[5].command_sent, 0);
  EXPECT_EQ(h.state(6), TrackingState::kHold) << "nothing leaves HOLD but the operator";
  EXPECT_EQ(h.records.all[7].operator_command, 1 + std::uint8_t(OperatorCommand::kResume));
  EXPECT_EQ(h.state(7), TrackingState::kTrack);
  EXPECT_EQ(h.records.all[7].command_sent, 1) << "the resume approves the move the operator saw";
  EXPECT_LT((h.couch.target - translation(-3.5, 0, 0)).norm(), 1e-9);
  for (std::size_t i = 9; i < 12; ++i) EXPECT_EQ(h.records.all[i].beam_permit, 1) << "cycle " << i;
}

TEST(LoopStates, ManyFailuresFaultAndOnlyAResetLeavesTheFault) {
  // Runs 3 to 12 fail: HOLD at the third, FAULT at the tenth in a row (fault_after_failures).
  // In FAULT nothing registers; a resume there, and a reset in TRACK, change nothing.
  Harness h([](int n) {
    Answer a = still_at(translation(0.5, 0, 0));
    a.fails = n >= 3 && n <= 12;
    return a;
  });
  CommandsAtCycles operator_input(
      {{1, OperatorCommand::kReset}, {15, OperatorCommand::kResume}, {17, OperatorCommand::kReset}});
  h.operator_input = &operator_input;
  h.settings.cycles = 22;
  const LoopSummary s = h.run();
  ASSERT_EQ(h.records.all.size(), 22u);
  EXPECT_EQ(h.state(1), TrackingState::kTrack) << "a reset in TRACK changes nothing";
  EXPECT_EQ(h.state(5), TrackingState::kHold);
  EXPECT_EQ(h.state(12), TrackingState::kFault);
  EXPECT_EQ(h.state(15), TrackingState::kFault) << "a resume does not leave a FAULT";
  EXPECT_EQ(h.registration->stages.size(), 13u + (22u - 17u)) << "nothing registers in FAULT";
  EXPECT_EQ(h.state(17), TrackingState::kTrack) << "reset: aligned again in its own cycle";
  EXPECT_EQ(h.registration->stages[13], RegistrationStage::kAlign);
  EXPECT_EQ(s.faults, 1);
  for (std::size_t i = 3; i < 17; ++i) EXPECT_EQ(h.records.all[i].command_sent, 0) << "cycle " << i;
}

// Cycles are numbered by period: a stall's skipped periods have no cycle (and no record).
TEST(LoopStates, OneStalledCycleIsAnOverrunAndThreeInARowHold) {
  Harness h([](int) { return still_at(translation(0.5, 0, 0)); });
  // A stall is how much longer than its period a cycle ran. Cycle 4 runs 1.5 periods over: 5
  // and 6 are skipped. Then 10, 12 and 14 each run 1 ns over: three overruns in a row.
  h.records.stall_ns = {{4, 150'000'000}, {10, 1}, {12, 1}, {14, 1}};
  h.settings.cycles = 14;
  const LoopSummary s = h.run();
  std::map<std::uint64_t, const JournalRecord*> by_cycle;
  for (const JournalRecord& r : h.records.all) by_cycle[r.cycle] = &r;
  std::string cycles;
  for (const auto& [n, r] : by_cycle) cycles += " " + std::to_string(n) + ":" + std::to_string(r->state);
  ASSERT_TRUE(by_cycle.count(4) && by_cycle.count(7) && by_cycle.count(16) && by_cycle.count(17)) << cycles;
  EXPECT_FALSE(by_cycle.count(5) || by_cycle.count(6)) << "skipped periods are no cycles";
  EXPECT_EQ(by_cycle[4]->overrun, 1);
  EXPECT_EQ(by_cycle[4]->skipped_periods, 2u) << "2.5 periods long: two whole ones skipped";
  EXPECT_EQ(by_cycle[7]->state, std::uint8_t(TrackingState::kTrack)) << "one overrun is counted, not held";
  EXPECT_EQ(by_cycle[12]->state, std::uint8_t(TrackingState::kTrack));
  EXPECT_EQ(by_cycle[16]->state, std::uint8_t(TrackingState::kHold)) << "three in a row hold";
  EXPECT_EQ(by_cycle[16]->gate_reason, std::uint8_t(GateReason::kOverruns));
  EXPECT_EQ(by_cycle[16]->command_sent, 0);
  EXPECT_EQ(s.overruns, 4);
  EXPECT_EQ(s.skipped_periods, 5);
  EXPECT_EQ(s.holds, 1);
}

TEST(LoopStates, ARefusedSetUpMoveHoldsAndTheResumeAlignsAgain) {
  Harness h([](int) { return still_at(translation(1, 1, 0)); });
  h.couch.refuse = {0};  // the first command, the set-up move
  CommandsAtCycles operator_input({{4, OperatorCommand::kResume}});
  h.operator_input = &operator_input;
  h.settings.cycles = 8;
  const LoopSummary s = h.run();
  EXPECT_EQ(h.state(0), TrackingState::kHold);
  EXPECT_EQ(h.records.all[0].command_sent, 0);
  EXPECT_EQ(s.holds, 1);
  ASSERT_GE(h.registration->stages.size(), 5u);
  EXPECT_EQ(h.registration->stages[4], RegistrationStage::kAlign) << "the resume aligns again";
  EXPECT_EQ(h.state(4), TrackingState::kTrack) << "resumed: the set-up move is made now";
  EXPECT_EQ(h.records.all[4].beam_permit, 0) << "no beam in an alignment's cycle";
  EXPECT_TRUE(s.aligned);
  ASSERT_EQ(h.couch.commands.size(), 1u);
  EXPECT_LT((h.couch.target + translation(1, 1, 0)).norm(), 1e-9);
}

// A tracking command the couch refuses (nothing moved) holds in its own cycle, for that reason,
// with the beam off: the gate judges the refusal as one more input, and the state machine moves
// once (TRACK to HOLD).
TEST(LoopStates, ARefusedTrackingCommandHoldsInItsOwnCycleWithTheBeamOff) {
  Harness h([](int n) { return still_at(translation(1 + 0.1 * n, 0, 0)); });
  h.couch.refuse = {3};  // the set-up move is command 0; cycles 1, 2 and 3 each send one
  h.settings.cycles = 6;
  const LoopSummary s = h.run();
  ASSERT_EQ(h.records.all.size(), 6u);
  for (int cycle : {1, 2}) {
    EXPECT_EQ(h.state(cycle), TrackingState::kTrack) << cycle;
    EXPECT_EQ(h.records.all[cycle].beam_permit, 1) << cycle;
    EXPECT_EQ(h.records.all[cycle].command_sent, 1) << cycle;
  }
  EXPECT_EQ(h.state(3), TrackingState::kHold);
  EXPECT_EQ(h.records.all[3].gate_decision, std::uint8_t(GateDecision::kHold));
  EXPECT_EQ(h.records.all[3].gate_reason, std::uint8_t(GateReason::kCommandRefused));
  EXPECT_EQ(h.records.all[3].command_sent, 0);
  EXPECT_EQ(h.records.all[3].beam_permit, 0);
  EXPECT_EQ(h.state(5), TrackingState::kHold) << "held until the operator resumes";
  EXPECT_EQ(s.holds, 1);
  ASSERT_EQ(s.transitions.size(), 3u) << "IDLE to ALIGN, ALIGN to TRACK, TRACK to HOLD";
  EXPECT_EQ(s.transitions[2].cycle, 3);
  EXPECT_EQ(s.transitions[2].from, TrackingState::kTrack);
  EXPECT_EQ(s.transitions[2].to, TrackingState::kHold);
  EXPECT_EQ(h.couch.commands.size(), 3u) << "the set-up move and two corrections";
}

// A command left unanswered may have moved the couch: a device fault in its own cycle, the couch
// held and the beam off there and after.
TEST(LoopStates, AnUnansweredCommandFaultsInItsOwnCycleWithTheCouchHeldAndTheBeamOff) {
  Harness h([](int n) { return still_at(translation(1 + 0.1 * n, 0, 0)); });
  h.couch.time_out = {2};
  h.settings.cycles = 5;
  const LoopSummary s = h.run();
  ASSERT_EQ(h.records.all.size(), 5u);
  EXPECT_EQ(h.state(1), TrackingState::kTrack);
  EXPECT_EQ(h.records.all[1].beam_permit, 1);
  EXPECT_EQ(h.state(2), TrackingState::kFault);
  EXPECT_EQ(h.records.all[2].beam_permit, 0);
  for (int cycle : {3, 4}) {
    EXPECT_EQ(h.state(cycle), TrackingState::kFault) << "only a reset leaves FAULT: " << cycle;
    EXPECT_EQ(h.records.all[cycle].beam_permit, 0) << cycle;
    EXPECT_EQ(h.records.all[cycle].command_sent, 0) << cycle;
  }
  EXPECT_EQ(s.faults, 1);
  EXPECT_EQ(h.couch.holds, 2) << "held on entry into FAULT, and again at the run's end";
  ASSERT_EQ(s.transitions.size(), 3u) << "IDLE to ALIGN, ALIGN to TRACK, TRACK to FAULT";
  EXPECT_EQ(s.transitions[2].from, TrackingState::kTrack);
  EXPECT_EQ(s.transitions[2].to, TrackingState::kFault);
}

TEST(LoopStates, AStopHoldsTheCouchAndEndsTheRun) {
  Harness h([](int n) { return still_at(translation(0.1 * n, 0, 0)); });
  CommandsAtCycles operator_input({{6, OperatorCommand::kStop}});
  h.operator_input = &operator_input;
  const LoopSummary s = h.run();
  EXPECT_EQ(s.ended, "operator stop");
  ASSERT_EQ(h.records.all.size(), 7u) << "the stop's cycle is recorded, and is the last";
  EXPECT_EQ(h.state(6), TrackingState::kIdle);
  EXPECT_EQ(h.registration->stages.size(), 6u) << "the stop's cycle registers nothing";
  EXPECT_EQ(h.couch.holds, 2) << "held at the stop, and again at the run's end";
  EXPECT_EQ(h.records.all[6].beam_permit, 0);
  EXPECT_FALSE(h.couch.beam_permit);
}

// A commissioned scene's verdict judges tracking cycles too (issue 52): a result whose similarity
// falls below the floor, though above the gate's ratio to the alignment (0.75 / 0.9 = 0.83 >
// 0.7), is no result: skipped, nothing moves. Without judge_tracking the gate alone applies it.
TEST(LoopStates, ATrackingResultBelowTheVerdictsFloorIsSkippedWhenTrackingIsJudged) {
  VerdictLimits limits;
  limits.measure = "ncc";
  limits.min_similarity = 0.8;
  limits.min_view_ratio = 0.5;
  limits.envelope = {10, 5};
  for (const bool judged : {true, false}) {
    SCOPED_TRACE(judged ? "tracking judged" : "alignment judged only");
    Harness h([](int n) {
      Answer a = still_at(translation(0.3 * n, 0, 0));
      if (n == 5) a.similarity = 0.75;
      return a;
    });
    h.settings.verdict = limits;
    h.settings.judge_tracking = judged;
    (void)h.run();
    ASSERT_EQ(h.records.all.size(), 20u);
    const JournalRecord& r = h.records.all[5];
    if (judged) {
      EXPECT_EQ(r.gate_decision, std::uint8_t(GateDecision::kSkip));
      EXPECT_EQ(r.gate_reason, std::uint8_t(GateReason::kLowSimilarity));
      EXPECT_EQ(r.command_sent, 0);
      EXPECT_EQ(h.couch.commands.size(), 18u) << "every tracking cycle moves but the one judged wrong";
    } else {
      EXPECT_EQ(r.gate_decision, std::uint8_t(GateDecision::kApply));
      EXPECT_EQ(h.couch.commands.size(), 19u);
    }
    EXPECT_EQ(h.state(6), TrackingState::kTrack) << "one skip is no hold";
  }
}

TEST(LoopStates, ALoopWhosePlansCannotBeReadiedIsRefused) {
  Harness h([](int) { return Answer{}; });
  h.registration->prepare_error = invalid_argument("no such level");
  auto loop = h.create();
  ASSERT_FALSE(loop.ok());
  EXPECT_NE(loop.status().message().find("no such level"), std::string::npos) << loop.status().message();
}

}  // namespace
}  // namespace lftrack::loop
