// The simulated closed loop end to end on a small version of the built-in scene (0.8 mm
// detector pixels, small light fields; frames from a separate finer field, or ray-cast): tracking
// error, states, the journal's contents, a sudden shift with an operator resume, lost frames,
// and zero heap allocations in 1,000 steady-state cycles.

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <string>
#include <thread>

#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <vector>

#include "filling_disk.hpp"
#include "lftrack/loop/allocation_counter.hpp"
#include "lftrack/records/journal_reader.hpp"
#include "lftrack/records/loop_json.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "loop_fixture.hpp"

namespace lftrack::session {

using loop::BeamWithheld;
using loop::GateDecision;
using loop::GateReason;
using loop::JournalRecord;
using loop::LoopSummary;
using loop::LoopTransition;
using loop::OperatorCommand;
using loop::OperatorRefusal;
using loop::process_allocation_count;
using loop::TrackingEvent;
using loop::TrackingState;

using records::read_journal;
using records::to_json;
namespace {

TEST_F(ClosedLoop, TracksDriftAndBreathingWithoutAllocatingInThousandCycles) {
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
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
  EXPECT_EQ(first.beam_permit, 0) << "the alignment's cycle";
  EXPECT_EQ(first.beam_withheld, std::uint8_t(BeamWithheld::kAlignment));
  // The couch (0.1 s latency) has not begun the set-up move at the next frame: the beam waits.
  const JournalRecord& second = r.journal.records[1];
  EXPECT_EQ(second.gate_decision, std::uint8_t(GateDecision::kApply));
  EXPECT_EQ(second.beam_permit, 0);
  EXPECT_EQ(second.beam_withheld, std::uint8_t(BeamWithheld::kOutOfPlace));
  EXPECT_GT(second.true_residual_mm, 2.0);
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

// On the simulated clock a run is deterministic: two runs of the same seed register, command
// and read back the same numbers bit for bit, whatever the host's uptime when each starts and
// however long each registration takes (only the wall-clock fields differ). The motion
// predictor once took absolute seconds as doubles, and two runs drifted apart from the third
// cycle on: 0.05 mm in the residual's p95 after 120 cycles. And a tracking registration's
// wall-time budget, which a loaded host reached at different moments, no longer applies there.
TEST_F(ClosedLoop, TwoRunsOfOneSeedOnTheSimulatedClockAreTheSameBitForBit) {
  const LoopRun first = run_loop(kBreathing, 120);
  std::this_thread::sleep_for(std::chrono::milliseconds(7));  // another origin for the clock
  const LoopRun second = run_loop(kBreathing, 120);
  ASSERT_EQ(first.journal.records.size(), 120u);
  ASSERT_EQ(second.journal.records.size(), 120u);
  EXPECT_NE(first.journal.records[0].cycle_start_ns, second.journal.records[0].cycle_start_ns);
  for (std::size_t i = 0; i < 120; ++i) {
    const JournalRecord& a = first.journal.records[i];
    const JournalRecord& b = second.journal.records[i];
    SCOPED_TRACE("cycle " + std::to_string(i));
    EXPECT_EQ(a.evaluations, b.evaluations);
    EXPECT_EQ(a.state, b.state);
    EXPECT_EQ(a.command_sent, b.command_sent);
    EXPECT_EQ(a.true_residual_mm, b.true_residual_mm);
    EXPECT_EQ(a.frame_time_ns[0] - a.cycle_start_ns, b.frame_time_ns[0] - b.cycle_start_ns);
    for (int k = 0; k < 6; ++k) {
      EXPECT_EQ(a.pose_delta[k], b.pose_delta[k]) << k;
      EXPECT_EQ(a.command[k], b.command[k]) << k;
      EXPECT_EQ(a.readback[k], b.readback[k]) << k;
    }
    if (::testing::Test::HasFailure()) break;  // the first cycle that differs says enough
  }
  EXPECT_EQ(*first.summary.residual_p95_mm, *second.summary.residual_p95_mm);
}

TEST_F(ClosedLoop, SuddenShiftHoldsInOneCycleAndRecoversAfterResume) {
  const std::string motion =
      "motion:\n  breathing: {amplitude_mm: [0, 1, 2], period_s: 4}\n"
      "  shifts: [{time_s: 3.0, translation_mm: [0, 8, 0]}]\n";
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
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
  // The beam waits for the patient: not with the approved move, nor while the couch (0.1 s
  // latency, 40 mm/s) is still more than a step from its target at the read-back.
  EXPECT_EQ(records[resumed].beam_permit, 0);
  EXPECT_EQ(records[resumed].beam_withheld, std::uint8_t(BeamWithheld::kApprovedStep));
  ASSERT_LT(resumed + 1, records.size());
  EXPECT_EQ(records[resumed + 1].beam_permit, 0);
  EXPECT_NE(records[resumed + 1].beam_withheld, 0) << "the couch has not arrived";
  int beam_after_resume = 0;
  for (std::size_t i = resumed; i < records.size(); ++i) {
    if (records[i].beam_permit == 0) continue;
    ++beam_after_resume;
    EXPECT_LT(records[i].true_residual_mm, 2.0) << "cycle " << i << ": the beam on with the patient out of place";
  }
  EXPECT_GT(beam_after_resume, 20) << "and then tracks with the beam";
  bool recovered = false;
  for (std::size_t i = resumed; i <= resumed + 5 && i < records.size(); ++i)
    recovered = recovered || records[i].true_residual_mm < 0.5;
  EXPECT_TRUE(recovered) << "residual back under 0.5 mm within 5 cycles of the resume";
  EXPECT_EQ(r.summary.holds, 1);
  EXPECT_EQ(r.summary.faults, 0);
}

// An outside probe's case: a set-up error of 1.9 mm on each axis (each within the 2 mm step
// limit) is 3.3 mm out of place, and the beam came on in the second cycle, before the couch (0.1 s
// latency) had moved. The beam waits on the straight-line distance from the plan.
TEST_F(ClosedLoop, ASetUpErrorWithinTheStepLimitOnEachAxisStillWaitsForTheCouch) {
  const std::string motion = "motion:\n  setup_error: {translation_mm: [1.9, -1.9, 1.9], rotation_deg: [0, 0, 0]}\n";
  const LoopRun r = run_loop(motion, 12, {}, kRayCastFrames);
  const auto& records = r.journal.records;
  ASSERT_EQ(records.size(), 12u);
  int withheld = 0, with_beam = 0;
  for (std::size_t i = 0; i < records.size(); ++i) {
    const JournalRecord& rec = records[i];
    SCOPED_TRACE("cycle " + std::to_string(i));
    EXPECT_EQ(rec.state, std::uint8_t(TrackingState::kTrack));
    withheld += rec.beam_withheld == std::uint8_t(BeamWithheld::kOutOfPlace);
    if (rec.beam_permit == 0) continue;
    ++with_beam;
    EXPECT_LT(rec.true_residual_mm, 2.5) << "the beam on with the patient out of place";
  }
  EXPECT_GE(withheld, 1) << "the couch had not begun the set-up move at the second frame";
  EXPECT_GE(with_beam, 8) << "and then the beam tracks";
}

// A couch that never arrives (0.05 mm/s for a 3 mm set-up move: a minute) keeps the beam off. After
// safety.max_beam_withheld_s (here 2 s, 20 cycles from cycle 1, the first after the alignment's)
// the loop holds and says why, and the couch stops, instead of the move going out cycle after
// cycle with nobody told.
TEST_F(ClosedLoop, ACouchThatNeverArrivesHoldsOnceTheBeamHasWaitedTheLongestItMay) {
  edit_scene_ = [](Scene& scene) {
    scene.actuator.dynamics.max_speed_mm_s = 0.05;
    scene.safety.max_beam_withheld_s = 2.0;
  };
  const std::string motion = "motion:\n  setup_error: {translation_mm: [0, 3, 0], rotation_deg: [0, 0, 0]}\n";
  const LoopRun r = run_loop(motion, 30, {}, kLightFieldFrames);
  const auto& records = r.journal.records;
  ASSERT_EQ(records.size(), 30u);
  std::size_t held_at = records.size();
  for (std::size_t i = 0; i < records.size() && held_at == records.size(); ++i)
    if (records[i].state == std::uint8_t(TrackingState::kHold)) held_at = i;
  ASSERT_LT(held_at, records.size()) << "the loop never held";
  EXPECT_GE(held_at, 21u) << "not before the beam had waited 2 s in TRACK (20 cycles of 100 ms)";
  EXPECT_LE(held_at, 22u);
  EXPECT_EQ(records[held_at].gate_decision, std::uint8_t(GateDecision::kHold));
  EXPECT_EQ(records[held_at].gate_reason, std::uint8_t(GateReason::kNotInPlace))
      << to_string(GateReason(records[held_at].gate_reason));
  EXPECT_NE(records[held_at].hold_id, 0u) << "a HOLD the operator's resume must name";
  for (std::size_t i = 0; i < records.size(); ++i) {
    SCOPED_TRACE("cycle " + std::to_string(i));
    EXPECT_EQ(records[i].beam_permit, 0) << "the patient was never in place";
    if (i < held_at) {
      EXPECT_TRUE(records[i].state == std::uint8_t(TrackingState::kTrack) ||
                  records[i].state == std::uint8_t(TrackingState::kAlign));
      EXPECT_NE(records[i].beam_withheld, std::uint8_t(BeamWithheld::kNo));
    } else {
      EXPECT_EQ(records[i].state, std::uint8_t(TrackingState::kHold)) << "nothing resumes without the operator";
      EXPECT_EQ(records[i].command_sent, 0) << "held: nothing sent";
    }
  }
  EXPECT_EQ(r.summary.holds, 1);
}

// Issue 18, item 1: resumes sent while tracking once waited in the socket's queue and approved the
// next HOLD. Now they are discarded (and journaled) when they arrive; the HOLD is left only by a
// resume sent after it began that names its id.
TEST_F(ClosedLoop, ResumesSentWhileTrackingNeverApproveALaterHold) {
  const std::string motion =
      "motion:\n  breathing: {amplitude_mm: [0, 1, 2], period_s: 4}\n"
      "  shifts: [{time_s: 3.0, translation_mm: [0, 8, 0]}]\n";
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.control_socket = dir_.path() / "control.sock";
  const auto me = dir_.path() / "operator.sock";
  std::vector<std::string> replies;  // what the socket answered, in order
  unsigned hold_id_seen = 0;
  const auto operator_thread = [&](LoopSession&) {
    return std::thread([&] {
      const int fd = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
      sockaddr_un self{}, to{};
      self.sun_family = to.sun_family = AF_UNIX;
      std::strncpy(self.sun_path, me.c_str(), sizeof(self.sun_path) - 1);
      std::strncpy(to.sun_path, options.control_socket.c_str(), sizeof(to.sun_path) - 1);
      if (::bind(fd, reinterpret_cast<const sockaddr*>(&self), sizeof self) != 0) return;
      timeval timeout{0, 20000};
      ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
      timeval send_timeout{10, 0};
      ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &send_timeout, sizeof send_timeout);
      const auto send = [&](const char* text) {
        return ::sendto(fd, text, std::strlen(text), 0, reinterpret_cast<const sockaddr*>(&to), sizeof to) > 0;
      };
      // The next reply; empty when none came in 20 ms.
      const auto next_reply = [&]() -> std::string {
        char buffer[256];
        const ssize_t n = ::recv(fd, buffer, sizeof buffer, 0);
        if (n <= 0) return {};
        replies.emplace_back(buffer, std::size_t(n));
        return replies.back();
      };
      // Until `done` says so, sending `request` every 100 ms (the loop answers about once a
      // cycle; the kernel keeps ten replies, so nothing is sent faster than they are read). Gives
      // up when the loop has ended (its socket is removed) or after ten minutes.
      const auto until = [&](const char* request, const std::function<bool(const std::string&)>& done) {
        for (int i = 0; i < 30000 && std::filesystem::exists(options.control_socket); ++i) {
          if (i % 5 == 0) send(request);
          const std::string reply = next_reply();
          if (!reply.empty() && done(reply)) return true;
        }
        return false;
      };
      // Forty resumes, guessing a HOLD id, sent as fast as the socket takes them (the kernel
      // queues ten): the old loop took one per cycle, so some were still waiting at the HOLD.
      for (int i = 0; i < 40; ++i) send("resume 1");
      // The HOLD's id, as the operator learns it: the status reply "HOLD <id> cycle <n>: ...".
      if (!until("status", [&](const std::string& reply) {
            return std::sscanf(reply.c_str(), "HOLD %u", &hold_id_seen) == 1;
          }))
        return;
      // Waits until the loop has gone on to a later cycle than the one now answering, so that
      // what was just sent is journaled in a cycle of its own (the journal keeps the last refusal
      // and the strongest command per cycle): status replies end "cycle <n>: <reason>".
      const auto next_cycle = [&] {
        long long first = -1;
        return until("status", [&](const std::string& reply) {
          const std::size_t at = reply.find(" cycle ");
          long long n = -1;
          if (at == std::string::npos || std::sscanf(reply.c_str() + at, " cycle %lld", &n) != 1) return false;
          if (first < 0) first = n;
          return n > first;
        });
      };
      const std::string wrong = "resume " + std::to_string(hold_id_seen == 999999 ? 100000 : hold_id_seen + 1);
      if (!until(wrong.c_str(), [](const std::string& reply) { return reply.rfind("refused: names another HOLD", 0) == 0; }))
        return;
      if (!next_cycle()) return;
      // The right id: refused while the HOLD is younger than a second, then accepted.
      const std::string right = "resume " + std::to_string(hold_id_seen);
      if (until(right.c_str(), [](const std::string& reply) { return reply.rfind("accepted: resume", 0) == 0; }) &&
          next_cycle())
        send("quit");  // the loop ends here, not at its cycle cap
      ::close(fd);
    });
  };
  const LoopRun r = run_loop(motion, 400, options, kRayCastFrames, operator_thread);
  const auto& records = r.journal.records;
  EXPECT_EQ(r.summary.ended, "operator quit") << "the operator's thread went through to its end";
  ASSERT_GT(records.size(), 32u);
  int refused_while_tracking = 0;
  for (std::size_t i = 0; i < 30; ++i) {
    EXPECT_NE(records[i].state, std::uint8_t(TrackingState::kHold));
    refused_while_tracking += records[i].operator_refused;
  }
  EXPECT_EQ(refused_while_tracking, 40) << "every stale resume was taken, refused and journaled";
  EXPECT_EQ(records[30].state, std::uint8_t(TrackingState::kHold));
  EXPECT_EQ(records[30].hold_id, hold_id_seen);
  EXPECT_GE(hold_id_seen, 100000u) << "a random six-digit id, which no earlier command could name";
  std::size_t resumed = 0;
  bool wrong_id_refused = false;
  // The cycle that acted on the resume (on a loaded host its registration may be cut short by the
  // budget and the gate hold again in that same cycle: the resume is what this test is about).
  for (std::size_t i = 31; i < records.size() && resumed == 0; ++i) {
    if (records[i].operator_refusal == std::uint8_t(OperatorRefusal::kWrongHold)) wrong_id_refused = true;
    if (records[i].operator_command == 1 + int(OperatorCommand::kResume)) resumed = i;
    if (resumed == 0) {
      EXPECT_EQ(records[i].state, std::uint8_t(TrackingState::kHold)) << "cycle " << i;
    }
  }
  EXPECT_TRUE(wrong_id_refused) << "a resume for another id was refused and journaled";
  ASSERT_GE(resumed, 40u) << "the HOLD lasted until the operator's fresh resume, a second or more into it";
  bool too_soon_refused = false;
  for (std::size_t i = 31; i < resumed; ++i)
    too_soon_refused = too_soon_refused || records[i].operator_refusal == std::uint8_t(OperatorRefusal::kTooSoon);
  EXPECT_TRUE(too_soon_refused) << "the right id in the HOLD's first second was refused";
  EXPECT_EQ(records[resumed].previous_state, std::uint8_t(TrackingState::kHold));
  EXPECT_EQ(records[resumed - 1].hold_id, hold_id_seen) << "the HOLD it answered";
  EXPECT_GE(r.summary.holds, 1);
  EXPECT_GE(r.summary.operator_refused, 41);
  EXPECT_FALSE(std::filesystem::exists(options.control_socket)) << "removed at the end";
}

// Issue 18, item 4: the loop judges every registration as `lftrack register` does. Here the
// scene's pose envelope is 1 mm while the set-up error is about 4 mm: the alignment lands outside
// it, is rejected with the verdict's reason (which only the verdict gives), and nothing moves. A
// rejected alignment is a skipped cycle: ALIGN tries again with the next pair, and the gate's
// third failure in a row holds (the operator decides).
TEST_F(ClosedLoop, ARegistrationTheVerdictRejectsMovesNothing) {
  edit_scene_ = [](Scene& scene) { scene.envelope.translation_mm = 1.0; };
  const LoopRun r = run_loop(kBreathing, 4, {}, kLightFieldFrames);
  const auto& records = r.journal.records;
  ASSERT_EQ(records.size(), 4u);
  EXPECT_EQ(records[0].gate_reason, std::uint8_t(GateReason::kOutsideEnvelope));
  EXPECT_EQ(records[0].state, std::uint8_t(TrackingState::kAlign)) << "skipped: ALIGN tries the next pair";
  EXPECT_EQ(records[2].state, std::uint8_t(TrackingState::kHold)) << "the third failure: the operator decides";
  EXPECT_EQ(records[3].state, std::uint8_t(TrackingState::kHold));
  for (const JournalRecord& rec : records) {
    EXPECT_EQ(rec.command_sent, 0);
    EXPECT_EQ(rec.beam_permit, 0);
  }
  EXPECT_EQ(r.summary.commands, 0);
}

// The verdict's view check (each view registered alone from the result): at the alignment, and
// in a judged scene on every Nth accepted tracking cycle; on the simulated clock it always fits.
TEST_F(ClosedLoop, TheViewCheckRunsAtTheAlignmentAndEveryNthTrackingCycle) {
  edit_scene_ = [](Scene& scene) {
    scene.loop.judge_tracking = true;
    scene.verdict_checks.view_check_every = 4;
  };
  const LoopRun judged = run_loop(kBreathing, 14, {}, kLightFieldFrames);
  expect_tracks_every_cycle(judged.summary, 14);
  EXPECT_EQ(judged.summary.view_check_every, 4);
  EXPECT_EQ(judged.summary.view_checks, 1 + 13 / 4) << "the alignment and tracking cycles 4, 8 and 12";
  EXPECT_EQ(judged.summary.view_checks_refused, 0);
  EXPECT_EQ(judged.summary.view_checks_out_of_time, 0);
  EXPECT_GT(judged.summary.view_check_max_ms, 0);
  EXPECT_EQ(to_json(judged.summary)["view_check"]["checks"], 4);

  edit_scene_ = [](Scene& scene) { scene.verdict_checks.view_check_every = 4; };  // tracking not judged
  EXPECT_EQ(run_loop(kBreathing, 6, {}, kLightFieldFrames).summary.view_checks, 1) << "the alignment only";
  edit_scene_ = [](Scene& scene) { scene.verdict_checks.max_view_shift_mm = 0; };  // no view check
  const LoopSummary off = run_loop(kBreathing, 6, {}, kLightFieldFrames).summary;
  EXPECT_EQ(off.view_check_every, -1);
  EXPECT_EQ(off.view_checks, 0);
}

TEST_F(ClosedLoop, LostFramesSkipThenHoldThenFaultWithoutMoving) {
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.frames.drop_from = 10;  // exposures 10.. never arrive
  options.frames.drop_to = 1000;
  const LoopRun r = run_loop(kBreathing, 30, options);
  const auto& records = r.journal.records;
  ASSERT_EQ(records.size(), 30u);
  EXPECT_EQ(records[10].gate_decision, std::uint8_t(GateDecision::kSkip));
  EXPECT_EQ(records[10].gate_reason, std::uint8_t(GateReason::kNoFrames));
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

// The session's couch, except that it refuses its first `refusals` commands (a fault it knows
// of, as a CAN robot in error-passive does): nothing is sent, nothing moves.
class RefusingCouch final : public drivers::ForwardingActuator {
 public:
  RefusingCouch(drivers::Actuator* inner, int refusals) : drivers::ForwardingActuator(inner), refusals_(refusals) {}
  drivers::DeviceStatus command(const tracking::Vector6d& c, drivers::Deadline d) override {
    if (refusals_ > 0) {
      --refusals_;
      return drivers::DeviceStatus::kRefused;
    }
    return inner_->command(c, d);
  }

 private:
  int refusals_;
};

// Most likely what the chaos soak met (seed 23, segment 34, a CAN segment, "a command before any
// alignment"): the couch refused the set-up move, the loop held, and it had nonetheless counted itself aligned, so the operator's resume
// went straight to TRACK and made the whole set-up move there, as a tracking correction with
// the beam permitted. An alignment is done when its set-up move is accepted: a refused one
// holds as an alignment that failed, and the resume aligns again (beam off while it moves).
TEST_F(ClosedLoop, ARefusedSetUpMoveIsAnAlignmentThatFailedAndTheResumeAlignsAgain) {
  std::unique_ptr<RefusingCouch> couch;
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.auto_resume_s = 1.0;
  options.hooks.wrap_actuator = [&](drivers::Actuator* inner) -> drivers::Actuator* {
    couch = std::make_unique<RefusingCouch>(inner, 1);
    return couch.get();
  };
  const LoopRun r = run_loop(kBreathing, 30, options);
  const auto& records = r.journal.records;
  ASSERT_EQ(records.size(), 30u);
  const JournalRecord& refused = records[0];
  EXPECT_EQ(refused.previous_state, std::uint8_t(TrackingState::kAlign));
  EXPECT_EQ(refused.state, std::uint8_t(TrackingState::kHold));
  EXPECT_EQ(refused.gate_reason, std::uint8_t(GateReason::kCommandRefused));
  EXPECT_EQ(refused.event, 1 + int(TrackingEvent::kAlignFailed));
  EXPECT_EQ(refused.command_sent, 0);
  EXPECT_EQ(refused.beam_permit, 0);
  std::size_t first_move = 0;
  for (std::size_t i = 1; i < records.size() && first_move == 0; ++i) {
    if (records[i].command_sent != 0) first_move = i;
    if (first_move == 0) {
      EXPECT_EQ(records[i].beam_permit, 0) << "cycle " << i;
    }
  }
  ASSERT_GT(first_move, 0u) << "the operator resumed and the loop aligned";
  const JournalRecord& aligned = records[first_move];
  EXPECT_EQ(aligned.event, 1 + int(TrackingEvent::kAligned)) << "the resume went back to ALIGN";
  EXPECT_EQ(aligned.state, std::uint8_t(TrackingState::kTrack));
  EXPECT_EQ(aligned.beam_permit, 0) << "no beam while the set-up move is made";
  EXPECT_NEAR(aligned.command[0], -3.0, 0.6) << "the set-up move (3 mm, and breathing of 0.5 mm on x)";
  EXPECT_EQ(records.back().state, std::uint8_t(TrackingState::kTrack));
  EXPECT_TRUE(r.summary.aligned);
}

}  // namespace
}  // namespace lftrack::session

namespace lftrack::session {
namespace {

// A treatment is not run unrecorded: when the journal's disk fills up, the loop holds, and
// every record written before the failure is still readable. On the simulated clock the hold
// comes at the cycle after the record that failed, however slow the disk is to say so and however
// the writer thread is scheduled (a loaded CI host once let the loop run past its 40th cycle).
TEST_F(ClosedLoop, AJournalDiskThatFillsUpHoldsTheLoopAndKeepsWhatWasWritten) {
  constexpr std::size_t kFrame = 8 + sizeof(JournalRecord) + 4;
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.journal = dir_.path() / "journal.lfj";
  // 20 cycles, then the disk is full, and slow to say so: the writer thread learns of it long
  // after the cycle that queued the record (on the simulated clock, many cycles later unless the
  // loop waits).
  options.journal_options.sink =
      std::make_shared<test::FillingDisk>(32 + 20 * kFrame + 10, std::chrono::milliseconds(700));
  options.journal_options.fsync_interval_ms = 10;
  auto prepared = prepare_scene(small_scene(kBreathing, kLightFieldFrames), "", pool_);
  ASSERT_TRUE(prepared.ok());
  options.cycles = 60;
  options.simulated_clock = true;
  options.light_field_dir = shared_light_field_dir(*prepared);
  auto session = LoopSession::create(*prepared, options, pool_);
  ASSERT_TRUE(session.ok()) << session.status().message();
  auto summary = (*session)->run();
  ASSERT_TRUE(summary.ok()) << summary.status().message();
  SCOPED_TRACE(to_json(*summary).dump());
  EXPECT_NE(summary->journal_error.find("disk full"), std::string::npos) << summary->journal_error;
  EXPECT_EQ(summary->holds, 1);
  // TRACK -> HOLD at cycle 21 (cycle 20's record failed; cycle 21's gate saw it), and FAULT
  // once the hold has lasted its longest with the journal still failed.
  ASSERT_EQ(summary->transitions.size(), 4u) << "start, aligned, hold, fault";
  const LoopTransition& held = summary->transitions[2];
  EXPECT_EQ(held.from, TrackingState::kTrack);
  EXPECT_EQ(held.to, TrackingState::kHold);
  EXPECT_STREQ(held.reason, "journal write failed");
  EXPECT_EQ(held.cycle, 21);
  EXPECT_EQ(summary->transitions[3].to, TrackingState::kFault);
  EXPECT_STREQ(summary->transitions[3].reason, "journal write failed");
  EXPECT_EQ(summary->states[std::size_t(TrackingState::kTrack)], 21) << "cycles 0 to 20 tracked";
  EXPECT_EQ(summary->commands, 21) << "nothing moved after the failure";
  auto journal = read_journal(options.journal);
  ASSERT_TRUE(journal.ok()) << journal.status().message();
  ASSERT_EQ(journal->records.size(), 20u);
  EXPECT_EQ(journal->torn_tail_bytes, 0u);
  for (std::size_t i = 0; i < 20; ++i) EXPECT_EQ(journal->records[i].cycle, i);
}

// On the real clock: one overrun is counted and its period skipped; several in a row hold.
TEST_F(ClosedLoop, OneOverrunIsCountedAndSeveralInARowHold) {
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.journal = dir_.path() / "journal.lfj";
  options.frames.stall_ms = 150;  // the period is 100 ms
  options.frames.stall_from = 20;
  options.frames.stall_to = 21;
  auto prepared = prepare_scene(small_scene(kBreathing, kLightFieldFrames), "", pool_);
  ASSERT_TRUE(prepared.ok());
  // A stalled cycle's frame is old at its decision; this test is about the overruns alone.
  prepared->scene.safety.max_frame_age_ms = 2000;
  options.cycles = 45;
  options.simulated_clock = false;
  options.light_field_dir = shared_light_field_dir(*prepared);
  // One stall first; then five in a row (exposure requests 35..39), after the first has passed.
  auto session = LoopSession::create(*prepared, options, pool_);
  ASSERT_TRUE(session.ok()) << session.status().message();
  auto single = (*session)->run();
  ASSERT_TRUE(single.ok());
  EXPECT_GE(single->overruns, 1);
  EXPECT_EQ(single->holds, 0) << "one overrun is counted, not held: " << to_json(*single).dump();

  options.frames.stall_from = 30;
  options.frames.stall_to = 35;
  options.journal = dir_.path() / "journal-several.lfj";  // a journal is never overwritten
  session = LoopSession::create(*prepared, options, pool_);
  ASSERT_TRUE(session.ok()) << session.status().message();
  auto several = (*session)->run();
  ASSERT_TRUE(several.ok());
  SCOPED_TRACE(to_json(*several).dump());
  EXPECT_GE(several->overruns, 3);
  EXPECT_EQ(several->holds, 1);
  ASSERT_FALSE(several->transitions.empty());
  EXPECT_STREQ(several->transitions.back().reason, "loop overruns");
  EXPECT_GE(several->transitions.back().cycle, 30);
}

}  // namespace
}  // namespace lftrack::session
