// The daily QA in a room whose couch is a device (issue 59): the couch served by `lftrack serve
// couch` in a process of its own, on Modbus TCP, with the room link the simulated detectors read
// (the hardware-in-the-loop room). The couch makes TG-135's known shifts, the loop on the real
// clock finds and undoes each, the beam-permit path holds when the room's frames are thrown away,
// and a couch that falls short of what it is told fails the offset test with the reason.

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "actuator_lock_holder.hpp"
#include "child_process.hpp"
#include "lftrack/drivers/forwarding_actuator.hpp"
#include "lftrack/qa/daily_qa.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/sim/room_link.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "qa_phantom_support.hpp"
#include "room_runs.hpp"

namespace lftrack::qa {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using tracking::Vector6d;

// `lftrack serve couch` on a port of the kernel's choosing, writing `dir`/room.link, with the QA
// room's couch dynamics (latency 0.1 s, 40 mm/s).
struct ServedCouch {
  std::unique_ptr<test::ChildProcess> process;
  int port = 0;
  explicit ServedCouch(const fs::path& dir) {
    process = std::make_unique<test::ChildProcess>(std::vector<std::string>{
        LFTRACK_BIN_PATH, "-q", "serve", "couch", "--modbus", "tcp:127.0.0.1:0", "--room",
        (dir / "room.link").string(), "--scene", test::qa_phantom_scene().string()});
    const std::optional<std::string> line =
        process->read_line(10s);  // "... modbus tcp 127.0.0.1:PORT; room link ..."
    if (line) port = std::atoi(line->c_str() + line->rfind(':', line->find(';')) + 1);
  }
};

// The QA phantom's room with its couch served: the scene's actuator the Modbus couch, its
// simulated detectors reading the couch's room link.
session::PreparedScene served_room(const fs::path& dir, int port, tracking::ThreadPool* pool) {
  auto scene = session::load_scene(test::qa_phantom_scene().string());
  EXPECT_TRUE(scene.ok()) << scene.status().message();
  scene->actuator.type = "modbus";
  scene->actuator.modbus.host = "127.0.0.1";
  scene->actuator.modbus.port = port;
  scene->actuator.modbus.response_timeout_s = 0.02;
  scene->actuator.modbus.reconnect_interval_s = 0.1;
  scene->sim.couch_link = (dir / "room.link").string();
  scene->loop.realtime.enforce = false;  // the latency chain is the CLI test's (daily_qa_cli_test.cpp)
  // The room's mechanics are under test, not the host's speed: on a host starved by its
  // neighbours (CI's other tests) the cold alignment outlasted the gate's 150 ms frame age three
  // times in a row ("the gate in ALIGN: stale frame, stale frame, stale frame"), and the loop held
  // as it must. The frame-age rule has tests of its own (tracking_loop_test.cpp).
  scene->safety.max_frame_age_ms = 1000;
  auto p = session::prepare_scene(*scene, "", pool);
  EXPECT_TRUE(p.ok()) << p.status().message();
  return std::move(p).value();
}

DailyQaOptions room_options(const fs::path& fields) {
  DailyQaOptions o;
  o.light_field_dir = fields;
  o.latency_cycles = 0;
  return o;
}

const QaCheck* room_check(const DailyQaReport& r, const std::string& name) {
  for (const QaCheck& c : r.checks)
    if (c.name == name) return &c;
  return nullptr;
}

// The QA phantom's room with its couch served in a process of its own, its light fields built
// (or found), for each test.
class RoomQa : public ::testing::Test {
 protected:
  void SetUp() override {
    fields = test::qa_phantom_fields(LFTRACK_BIN_PATH, test::qa_phantom_scene(), dir.path());
    ASSERT_FALSE(fields.empty()) << test::contents(dir.path() / "precompute.txt");
    couch = std::make_unique<ServedCouch>(dir.path());
    ASSERT_GT(couch->port, 0);
    p = served_room(dir.path(), couch->port, &pool);
  }

  test::TempDir dir;
  fs::path fields;
  std::unique_ptr<ServedCouch> couch;
  tracking::ThreadPool pool{2};
  session::PreparedScene p;
};

TEST_F(RoomQa, TheServedCouchMakesTheShiftsAndTheLoopFindsAndUndoesEach) {
  DailyQaOptions o = room_options(fields);
  // The room's mechanics are under test here, not the registration's rotation precision. On the
  // real clock the alignment's registration is cut by the cycle's budget and the couch follows
  // the tracking registrations' rotation scatter about a weak axis: on a loaded host the alignment
  // was off by up to 0.27 degree (an outside probe) and the couch's read-back by 0.32 (CI, beside
  // the other tests); 0.15-0.18 on a quiet host (BENCHMARKS.md). 1 degree keeps this test about
  // the couch and the loop; a shift the couch did not make, or undo, is off by millimetres.
  o.tolerance_deg = 1.0;
  // A host starved by its neighbours can cut an alignment's registration on the real clock (CI
  // once saw "the loop never aligned" for one shift; the couch was sent back and the QA went on):
  // the QA is run again, twice at most, and one run must pass every shift.
  Result<DailyQaReport> report = internal_error("not run");
  for (int attempt = 0; attempt < 3; ++attempt) {
    report = run_daily_qa(p, o, &pool);
    ASSERT_TRUE(report.ok()) << report.status().message();
    if (room_check(*report, "offset")->passed) break;
    std::cout << "attempt " << attempt + 1 << ": " << room_check(*report, "offset")->why << "\n";
  }
  ASSERT_EQ(report->offsets.size(), 7u);
  for (const OffsetResult& shift : report->offsets) {
    EXPECT_TRUE(shift.passed) << shift.why;
    EXPECT_LT(shift.registration_error_mm, 0.25);
    EXPECT_LT(shift.couch_error_mm, 0.25) << "the couch's read-back moved back by the shift";
  }
  ASSERT_NE(room_check(*report, "beam"), nullptr);
  EXPECT_TRUE(room_check(*report, "beam")->passed)
      << room_check(*report, "beam")->why << "; " << room_check(*report, "beam")->measured;
  EXPECT_TRUE(room_check(*report, "detector A")->passed) << room_check(*report, "detector A")->why;
}

// One program at a time drives a couch: while another process holds its lock (a treatment, a
// second QA) the QA is refused before it moves anything, and so is a treatment's loop session.
TEST_F(RoomQa, NoTwoProgramsDriveTheCouchAtOnce) {
  test::ActuatorLockHolder other(p.scene);
  ASSERT_TRUE(other.held());
  const std::string holder = "pid " + std::to_string(other.pid());

  auto qa = run_daily_qa(p, room_options(fields), &pool);
  ASSERT_FALSE(qa.ok());
  EXPECT_NE(qa.status().message().find("driven by another lftrack"), std::string::npos)
      << qa.status().message();
  EXPECT_NE(qa.status().message().find(holder), std::string::npos) << qa.status().message();

  session::LoopSessionOptions treatment;
  treatment.simulator = sim_devices::room_simulator();
  treatment.devices = session::SessionDevices::kScene;
  treatment.light_field_dir = fields;
  treatment.cycles = 5;
  auto session = session::LoopSession::create(p, treatment, &pool);
  ASSERT_FALSE(session.ok());
  EXPECT_NE(session.status().message().find(holder), std::string::npos) << session.status().message();

  other.end();
  auto free = session::LoopSession::create(p, treatment, &pool);
  EXPECT_TRUE(free.ok()) << free.status().message();
}

// A couch that takes the loop's commands and never moves (the loop's corrections never reach it).
class DeafCouch final : public drivers::ForwardingActuator {
 public:
  using ForwardingActuator::ForwardingActuator;
  drivers::DeviceStatus command(const Vector6d&, drivers::Deadline) override {
    return drivers::DeviceStatus::kOk;
  }
};

// The operator's Ctrl-C in a room (DailyQaOptions::interrupted): a couch on its way to a shift,
// or left at the shift by a loop that was stopped before it undid it, is sent back to where it
// stood before the shift; the QA ends with every check not made failed.
TEST_F(RoomQa, AnInterruptedShiftSendsTheCouchBackToWhereItStood) {
  const Vector6d none = Vector6d::Zero();
  auto start = move_couch_by(p, none, 10, nullptr);  // where the couch stands
  ASSERT_TRUE(start.ok()) << start.status().message();

  // Before the move: no new motion is started.
  Vector6d shift = Vector6d::Zero();
  shift << 6, -6, 6, 0, 0, 0;
  std::atomic<bool> stop{true};
  auto refused = move_couch_by(p, shift, couch_move_timeout_s(p.scene, shift), &stop);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("interrupted before the QA's shift"), std::string::npos)
      << refused.status().message();

  // On its way: the operator's Ctrl-C once the couch has left (its room link, as the simulated
  // detectors see it, 1 mm from where it stood); it is sent back the way it came.
  stop.store(false);
  auto link = sim::RoomLinkReader::open(dir.path() / "room.link");
  ASSERT_TRUE(link.ok()) << link.status().message();
  sim::RoomLinkSample at_start;
  ASSERT_TRUE((*link)->read(&at_start));
  std::atomic<bool> watching{true};
  std::thread operator_hand([&] {
    sim::RoomLinkSample now;
    while (watching.load() && !stop.load()) {
      if ((*link)->read(&now) && (now.couch_position - at_start.couch_position).head<3>().norm() > 1.0)
        stop.store(true);
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  });
  auto moving = move_couch_by(p, shift, couch_move_timeout_s(p.scene, shift), &stop);
  watching.store(false);
  operator_hand.join();
  ASSERT_TRUE(stop.load()) << "the couch left";
  ASSERT_FALSE(moving.ok());
  EXPECT_NE(moving.status().message().find("interrupted during the QA's shift"), std::string::npos)
      << moving.status().message();
  EXPECT_NE(moving.status().message().find("is back at"), std::string::npos) << moving.status().message();
  auto after_move = move_couch_by(p, none, 10, nullptr);
  ASSERT_TRUE(after_move.ok()) << after_move.status().message();
  EXPECT_LT((*after_move - *start).head<3>().norm(), 0.1) << "back where it stood";

  // At the shift: the shift made, the loop (whose commands never move the couch) stopped after its
  // first cycle; the QA sends the couch back.
  stop.store(false);
  DailyQaOptions o = room_options(fields);
  o.tolerance_deg = 1.0;
  shift << 0, 0, 8, 0, 0, 0;
  o.shifts = {shift};
  o.interrupted = &stop;
  int sessions = 0;
  std::unique_ptr<DeafCouch> deaf;
  o.hooks.wrap_actuator = [&](drivers::Actuator* inner) -> drivers::Actuator* {
    if (++sessions < 2) return inner;  // the alignment before the shift
    stop.store(true);                  // the couch has made the shift: the operator's Ctrl-C
    deaf = std::make_unique<DeafCouch>(inner);
    return deaf.get();
  };
  auto report = run_daily_qa(p, o, &pool);
  ASSERT_TRUE(report.ok()) << report.status().message();
  ASSERT_EQ(sessions, 2) << "nothing ran after the interrupted shift";
  ASSERT_EQ(report->offsets.size(), 1u);
  EXPECT_FALSE(report->offsets[0].passed);
  EXPECT_NE(report->offsets[0].why.find(kInterrupted), std::string::npos) << report->offsets[0].why;
  EXPECT_NE(report->offsets[0].why.find("the couch is back where it stood before the shift"),
            std::string::npos)
      << report->offsets[0].why;
  for (const char* name : {"beam", "latency"}) {
    ASSERT_NE(room_check(*report, name), nullptr) << name;
    EXPECT_EQ(room_check(*report, name)->why, kInterrupted) << name;
  }
  EXPECT_FALSE(report->passed());
  auto end = move_couch_by(p, none, 10, nullptr);
  ASSERT_TRUE(end.ok()) << end.status().message();
  EXPECT_LT((*end - *after_move).head<3>().norm(), 0.5) << "not left 8 mm off";
}

// A couch left displaced (a QA killed during a shift, a treatment's last corrections) is brought
// back by the alignment before the first shift, its set-up move made whole (the loop holds the
// couch as its one-cycle run ends, before a couch with latency has made the move): each shift is
// then made from where the plan puts the phantom, not on top of the displacement (an outside
// probe saw the QA shift a couch displaced by 10 mm to 20 mm from the plan).
TEST_F(RoomQa, ADisplacedCouchIsBroughtBackBeforeTheFirstShift) {
  Vector6d displaced = Vector6d::Zero();
  displaced << 4, -3, 5, 0, 0, 0;
  ASSERT_TRUE(move_couch_by(p, displaced, couch_move_timeout_s(p.scene, displaced), nullptr).ok());
  DailyQaOptions o = room_options(fields);
  o.tolerance_deg = 1.0;  // the mechanics, as above
  Vector6d shift = Vector6d::Zero();
  shift(2) = 8;
  o.shifts = {shift};
  auto report = run_daily_qa(p, o, &pool);
  ASSERT_TRUE(report.ok()) << report.status().message();
  ASSERT_EQ(report->offsets.size(), 1u);
  EXPECT_TRUE(report->offsets[0].passed) << report->offsets[0].why;
  EXPECT_LT(report->offsets[0].registration_error_mm, 0.25)
      << "the shift found alone, not with the displacement";
}

// The loop's commands reach the couch at 40 % of their size: it falls short of every correction.
class ShortCouch final : public drivers::ForwardingActuator {
 public:
  using ForwardingActuator::ForwardingActuator;
  drivers::DeviceStatus command(const Vector6d& correction, drivers::Deadline deadline) override {
    return inner_->command(0.4 * correction, deadline);
  }
};

TEST_F(RoomQa, ACouchThatFallsShortFailsTheOffsetTestWithTheReason) {
  DailyQaOptions o = room_options(fields);
  Vector6d shift = Vector6d::Zero();
  shift(2) = 8;
  o.shifts = {shift};
  o.offset_cycles = 3;  // the alignment and two corrections: 40 % each leaves over 2 mm
  std::unique_ptr<ShortCouch> short_couch;
  o.hooks.wrap_actuator = [&](drivers::Actuator* inner) -> drivers::Actuator* {
    short_couch = std::make_unique<ShortCouch>(inner);
    return short_couch.get();
  };
  auto report = run_daily_qa(p, o, &pool);
  ASSERT_TRUE(report.ok()) << report.status().message();
  ASSERT_EQ(report->offsets.size(), 1u);
  EXPECT_TRUE(report->offsets[0].aligned);
  EXPECT_LT(report->offsets[0].registration_error_mm, 0.25) << "the alignment itself was right";
  EXPECT_FALSE(report->offsets[0].passed);
  EXPECT_NE(report->offsets[0].why.find("the couch moved"), std::string::npos) << report->offsets[0].why;
  EXPECT_FALSE(room_check(*report, "offset")->passed);
}

}  // namespace
}  // namespace lftrack::qa
