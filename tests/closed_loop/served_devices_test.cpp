// The treatment room across processes: the loop (`lftrack run`'s session, kScene devices) drives
// a couch served by `lftrack serve couch` (Modbus TCP) or a robot served by `lftrack serve robot`
// (a CAN bridge socket), each a child process; the simulated detectors see the patient where that
// device has moved them through its room link. One parameterised suite runs every actuator kind
// (virtual, Modbus TCP, Modbus RTU over a pseudo-terminal pair, CAN) through the same
// closed-loop cases; the fault cases kill, stall, unplug
// and restart the servers mid-treatment (docs/faults.md, "Devices in other processes").

#include <fcntl.h>
#include <linux/videodev2.h>
#include <signal.h>
#include <sys/ioctl.h>
#include <stdlib.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <cmath>
#include <cstring>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "child_process.hpp"
#include "gige_host_lock.hpp"
#include "gvcp_probe.hpp"
#include "lftrack/records/loop_json.hpp"
#include "lftrack/sim/gige_fake_detector.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "loop_fixture.hpp"
#include "operator_client.hpp"

namespace lftrack::session {

using loop::GateReason;
using loop::JournalRecord;
using loop::TrackingState;

using records::to_json;
namespace {

using namespace std::chrono_literals;

// A short folder for sockets (a socket path has at most 107 bytes; the fixture's folders are
// named after the test).
class SocketDir {
 public:
  SocketDir() {
    char name[] = "/tmp/lfsXXXXXX";
    path_ = ::mkdtemp(name) != nullptr ? name : "";
  }
  ~SocketDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// A device server started as a child process, and where it listens.
struct ServedDevice {
  std::unique_ptr<test::ChildProcess> process;
  int port = 0;     // Modbus TCP
  std::string tty;  // Modbus RTU: the client's end of the server's pseudo-terminal pair
};

ServedDevice serve(const std::string& kind, const std::filesystem::path& dir, int port = 0) {
  ServedDevice d;
  const std::string bin = LFTRACK_BIN_PATH;
  std::vector<std::string> argv = {bin, "serve", kind == "can" ? "robot" : "couch"};
  if (kind == "modbus") {
    argv.insert(argv.end(), {"--modbus", "tcp:127.0.0.1:" + std::to_string(port)});
  } else if (kind == "rtu") {
    argv.insert(argv.end(), {"--modbus", "rtu:pty"});
  } else {
    argv.insert(argv.end(), {"--socket", (dir / "robot.sock").string()});
  }
  argv.insert(argv.end(), {"--room", (dir / "room.link").string(), "--control", (dir / "device.ctl").string()});
  // The couch's dynamics are the closed-loop scene's (latency 0.1 s, 40 mm/s).
  argv.insert(argv.end(), {"--scene", kBuiltinPhantom});
  d.process = std::make_unique<test::ChildProcess>(argv);
  const std::optional<std::string> line = d.process->read_line(10s);
  EXPECT_TRUE(line.has_value()) << "the server said where it listens";
  if (line && kind == "modbus") {
    const std::size_t colon = line->rfind(':', line->find(';'));
    d.port = std::atoi(line->c_str() + colon + 1);
    EXPECT_GT(d.port, 0) << *line;
  }
  if (line && kind == "rtu") {  // "... modbus rtu /dev/pts/N; room link ..."
    const std::size_t at = line->find("rtu ") + 4;
    d.tty = line->substr(at, line->find(';') - at);
    EXPECT_EQ(d.tty.rfind("/dev/", 0), 0u) << *line;
  }
  return d;
}

// The scene's actuator becomes the served device; its simulated detectors read the room link.
void use_served(Scene& scene, const std::string& kind, const std::filesystem::path& dir, int port,
                const std::string& tty = "") {
  scene.actuator.type = kind == "rtu" ? "modbus" : kind;
  if (kind == "rtu") {
    scene.actuator.modbus.transport = drivers::ModbusCouchOptions::Transport::kRtu;
    scene.actuator.modbus.serial_device = tty;
    // 115200 baud: a read-back's frames take ~5 ms; the line's copying thread may wait its turn
    // on a loaded host (the cycle's deadline still cuts the wait).
    scene.actuator.modbus.response_timeout_s = 0.15;
    scene.actuator.modbus.reconnect_interval_s = 0.1;
  } else if (kind == "modbus") {
    scene.actuator.modbus.host = "127.0.0.1";
    scene.actuator.modbus.port = port;
    scene.actuator.modbus.response_timeout_s = 0.02;
    scene.actuator.modbus.reconnect_interval_s = 0.1;
  } else {
    scene.actuator.can.bridge_path = (dir / "robot.sock").string();
    scene.actuator.can.reconnect_interval_s = 0.1;
  }
  scene.sim.couch_link = (dir / "room.link").string();
}

// Every cycle up to `last`, for a failure's message: state, gate, registration, the true residual,
// the registered pose and the command sent (translation mm, rotation deg).
std::string cycles_up_to(const std::vector<JournalRecord>& records, std::size_t last) {
  const auto six = [](const double* v) {
    std::string out;
    for (int i = 0; i < 6; ++i)
      out += (i == 0 ? "" : i == 3 ? " mm, " : " ") + std::to_string(i < 3 ? v[i] : tracking::rad_to_deg(v[i]));
    return out + " deg";
  };
  std::string out;
  for (std::size_t i = 0; i < records.size() && i <= last; ++i) {
    const JournalRecord& q = records[i];
    out += "\n  cycle " + std::to_string(q.cycle) + ": state " + std::to_string(q.state) + ", gate " +
           to_string(GateReason(q.gate_reason)) + ", sent " + std::to_string(q.command_sent) + ", evaluations " +
           std::to_string(q.evaluations) + ", registration " + std::to_string(q.registration_ms) +
           " ms, residual " + std::to_string(q.true_residual_mm) + " mm" + (q.overrun ? ", overrun" : "") +
           ", frames at " + std::to_string(q.frame_time_ns[0] - q.cycle_start_ns) + " " +
           std::to_string(q.frame_time_ns[1] - q.cycle_start_ns) + " ns, pose " + six(q.pose_delta) +
           ", command " + six(q.command) + ", read-back " + six(q.readback);
  }
  return out;
}

// After the set-up (removed in the first cycles) only the breathing's residual is left: under 1 mm
// every cycle and 0.4 mm on average. On the real clock how many cycles the couch takes to remove
// 4 mm depends on the host's load (CI once measured a whole-run mean of 0.516; after the set-up
// 0.18-0.24 mm on a loaded host; untracked, the breathing alone is about 3 mm).
void expect_breathing_removed(const std::vector<JournalRecord>& records) {
  double steady_sum_mm = 0;
  std::size_t steady_cycles = 0;
  for (std::size_t i = 10; i < records.size(); ++i) {
    EXPECT_LT(records[i].true_residual_mm, 1.0) << "cycle " << i;
    steady_sum_mm += records[i].true_residual_mm;
    ++steady_cycles;
  }
  ASSERT_GT(steady_cycles, 0u);
  EXPECT_LT(steady_sum_mm / double(steady_cycles), 0.4) << "mean residual after the set-up";
}

class EveryActuatorKind : public ClosedLoop, public ::testing::WithParamInterface<const char*> {
 protected:
  // Runs the scene with the actuator of this kind: the simulator's couch in process, or a
  // served one in a child process. The real clock: the served device moves on its own.
  LoopRun run_with_kind(const std::string& motion, std::int64_t cycles) {
    const std::string kind = GetParam();
    real_clock_ = true;
    LoopSessionOptions options;
    options.simulator = sim_devices::room_simulator();
    options.devices = SessionDevices::kScene;
    ServedDevice device;
    if (kind != "virtual") {
      device = serve(kind, sockets_.path());
      edit_scene_ = [&](Scene& s) { use_served(s, kind, sockets_.path(), device.port, device.tty); };
    }
    return run_loop(motion, cycles, options);
  }
  // The same, run again (three runs at most) while a run held before cycle `hold_before` with both
  // marks of a starved host: its first HOLD is a read-back that failed (kActuatorFault) in a cycle
  // that overran its period. On the real clock a loaded host can starve a cycle so (stress-ng
  // --cpu 2 did once in 12 runs), and the loop rightly holds; that run cannot show what the test
  // asserts. Any other HOLD is the run's result. `*held`: the first HOLD's cycle (0: none).
  LoopRun run_unstarved(const std::string& motion, std::int64_t cycles, std::size_t hold_before, std::size_t* held) {
    LoopRun r;
    for (int run = 0; run < 3; ++run) {
      r = run_with_kind(motion, cycles);
      *held = 0;
      for (std::size_t i = 0; i < r.journal.records.size() && *held == 0; ++i)
        if (r.journal.records[i].state == std::uint8_t(TrackingState::kHold)) *held = i;
      if (*held == 0 || *held >= hold_before) break;
      const JournalRecord& first = r.journal.records[*held];
      if (first.gate_reason != std::uint8_t(GateReason::kActuatorFault) || first.overrun == 0) break;
      std::cerr << "run " << run + 1 << ": held at cycle " << *held
                << " on a read-back the cycle's deadline cut (the cycle overran): run again\n";
    }
    return r;
  }
  SocketDir sockets_;
};

TEST_P(EveryActuatorKind, TracksBreathingEveryCycle) {
  std::size_t held = 0;
  const LoopRun r = run_unstarved(kBreathing, 60, 60, &held);
  SCOPED_TRACE(held == 0 ? std::string("no HOLD") : "the cycles to the first HOLD:" + cycles_up_to(r.journal.records, held + 1));
  expect_tracks_every_cycle(r.summary, 60);
  ASSERT_TRUE(r.summary.residual_p95_mm.has_value());
  expect_breathing_removed(r.journal.records);
}

TEST_P(EveryActuatorKind, ASuddenShiftHoldsAndMovesNothingAfter) {
  const std::string motion =
      "motion:\n  breathing: {amplitude_mm: [0, 1, 2], period_s: 4}\n"
      "  shifts: [{time_s: 3.0, translation_mm: [0, 8, 0]}]\n";
  // A run held by a starved host before the shift (run_unstarved) is run again.
  std::size_t held = 0;
  const LoopRun r = run_unstarved(motion, 50, 25, &held);
  ASSERT_EQ(r.journal.records.size(), 50u);
  const auto& records = r.journal.records;
  const std::string cycles_to_the_hold = cycles_up_to(records, held + 2);
  ASSERT_GT(held, 0u) << "the shift holds" << cycles_to_the_hold;
  // The cycle number, not the record's place: on the real clock an overrun skips periods, and
  // the shift comes at 3 s, the period of cycle 30, whatever was skipped before it.
  EXPECT_NEAR(double(records[held].cycle), 30.0, 1.0) << "in the cycle whose frame first shows it" << cycles_to_the_hold;
  EXPECT_EQ(records[held].gate_reason, std::uint8_t(GateReason::kStepTooLarge));
  for (std::size_t i = held; i < records.size(); ++i) {
    EXPECT_EQ(records[i].state, std::uint8_t(TrackingState::kHold)) << i;
    EXPECT_EQ(records[i].command_sent, 0) << "nothing sent in HOLD, cycle " << i;
    EXPECT_EQ(records[i].beam_permit, 0) << i;
  }
}

INSTANTIATE_TEST_SUITE_P(Room, EveryActuatorKind, ::testing::Values("virtual", "modbus", "rtu", "can"),
                         [](const ::testing::TestParamInfo<const char*>& kind) { return std::string(kind.param); });

// Faults across processes: the loop on the real clock with a control socket; the test is the
// operator and the one who kills, stalls, unplugs and restarts the servers. The loop runs until
// the test has seen what it waits for (each wait bounded, on a condition the loop's status
// shows), then is stopped: a fixed number of real-clock cycles ran out on a loaded host before the
// operator had brought the loop back (issue 54: the GigE power-cycle's frames "never resumed").
class ServedDeviceFaults : public ClosedLoop {
 protected:
  // Runs the served `kind` until `act(operator, device)`, run beside the loop, returns.
  LoopRun run_served(const std::string& kind, const std::function<void(OperatorClient&, ServedDevice&)>& act) {
    real_clock_ = true;
    device_ = serve(kind, sockets_.path());
    edit_scene_ = [&](Scene& s) { use_served(s, kind, sockets_.path(), device_.port); };
    LoopSessionOptions options;
    options.simulator = sim_devices::room_simulator();
    options.devices = SessionDevices::kScene;
    options.control_socket = sockets_.path() / "control.sock";
    return run_loop(kBreathing, 0, options, kLightFieldFrames, [&, options](LoopSession& session) {
      return std::thread([&, options] {
        OperatorClient op(options.control_socket, sockets_.path() / "operator.sock");
        act(op, device_);
        session.request_stop();
      });
    });
  }
  SocketDir sockets_;
  ServedDevice device_;
};

// The cycle the loop has reached (status), once it tracks at `at_least` or later; -1 if it did
// not within two minutes (an assertion then says so, well inside ctest's timeout).
long long tracking_cycle(OperatorClient& op, long long at_least) {
  const auto until = std::chrono::steady_clock::now() + 120s;
  while (std::chrono::steady_clock::now() < until) {
    const std::string reply = op.wait_for("TRACK", 10s);
    const long long c = OperatorClient::cycle_of(reply);
    if (c >= at_least) return c;
    std::this_thread::sleep_for(100ms);
  }
  return -1;
}

// After `from`: out of TRACK within two cycles, then safe (no beam, nothing sent) until the
// operator's command; back in TRACK by the end. Returns the place in `records` of the first record out of TRACK.
std::size_t expect_held_until_the_operator(const std::vector<JournalRecord>& records, long long from) {
  // `from` is a cycle number (the status says it); records are found by their cycle, not their
  // place in the journal, which skipped periods (overruns) put behind the cycle number.
  std::size_t out = 0;
  for (std::size_t i = 0; i < records.size() && out == 0; ++i)
    if (records[i].cycle >= std::uint64_t(std::max(from, 0LL)) && records[i].state != std::uint8_t(TrackingState::kTrack))
      out = i;
  EXPECT_GT(out, 0u) << "the loop left TRACK";
  if (out == 0) return 0;
  EXPECT_LE(records[out].cycle, std::uint64_t(from) + 3)
      << "within a cycle of the fault (the status was read up to a cycle before)";
  std::size_t back = 0;
  for (std::size_t i = out; i < records.size(); ++i) {
    if (records[i].state == std::uint8_t(TrackingState::kTrack)) {
      back = i;
      break;
    }
    EXPECT_EQ(records[i].beam_permit, 0) << "no beam, cycle " << i;
    EXPECT_EQ(records[i].command_sent, 0) << "nothing sent, cycle " << i;
    for (double v : records[i].command) EXPECT_TRUE(std::isfinite(v));
  }
  EXPECT_GT(back, out) << "the operator brought it back";
  // Only by the operator's command, journaled in the cycle that acted on it: the cycle back in
  // TRACK after a HOLD's resume, or an earlier one after a FAULT (reset, then a resume that
  // aligns again, and the alignment may take more than a cycle on a loaded host).
  bool operator_acted = false;
  for (std::size_t i = out; i <= back && back > 0; ++i) operator_acted = operator_acted || records[i].operator_command != 0;
  if (back > 0) {
    EXPECT_TRUE(operator_acted) << "only by the operator's command";
  }
  return out;
}

// The longest run of cycles that journaled no frame pair (frame sequence 0) in the stretch held
// from `from` (the first cycle out of TRACK) to the operator's resume. Not only the run at `from`:
// on a loaded host the loop may leave TRACK a cycle before the fault (an overrun, a stale pair)
// with a pair in hand, and the gap follows within the same hold.
std::size_t cycles_without_a_pair(const std::vector<JournalRecord>& records, std::size_t from) {
  std::size_t longest = 0, run = 0;
  for (std::size_t i = from; i < records.size() && records[i].state != std::uint8_t(TrackingState::kTrack); ++i) {
    run = records[i].frame_sequence[0] == 0 ? run + 1 : 0;
    longest = std::max(longest, run);
  }
  return longest;
}

// The held stretch from `from`, one line a cycle, for a failure's message.
std::string held_stretch(const std::vector<JournalRecord>& records, std::size_t from) {
  std::string s;
  for (std::size_t i = from; i < records.size() && i < from + 40 &&
                             (i == from || records[i].state != std::uint8_t(TrackingState::kTrack));
       ++i)
    s += "\n  cycle " + std::to_string(records[i].cycle) + ": state " + std::to_string(records[i].state) +
         ", frame " + std::to_string(records[i].frame_sequence[0]) + ", gate " +
         to_string(GateReason(records[i].gate_reason)) + (records[i].overrun ? ", overrun" : "");
  return s;
}

TEST_F(ServedDeviceFaults, KilledCouchServerHoldsUntilTheOperator) {
  long long killed_at = -1;
  bool tracked_again = false;
  const LoopRun r = run_served("modbus", [&](OperatorClient& op, ServedDevice& device) {
    killed_at = tracking_cycle(op, 20);
    device.process->signal(SIGKILL);
    device.process->wait(2s);
    // Held (the journal shows it stays so until the operator's command).
    const std::string during = op.wait_for_safe(30s);
    EXPECT_FALSE(during.empty()) << "held after the kill";
    // Restarted on the same port and room link: the couch stands where it stopped. The driver
    // reconnects outside the cycle; a resume before that holds again, and the operator resumes
    // the new HOLD.
    const int port = device.port;
    device = serve("modbus", sockets_.path(), port);
    tracked_again = op.bring_back_to_track(60s);
    const long long back_at = OperatorClient::cycle_of(op.ask("status"));
    if (tracked_again && back_at >= 0) op.wait_for_cycle(back_at + 20, 30s);  // the couch settles
  });
  ASSERT_GE(killed_at, 20);
  EXPECT_TRUE(tracked_again);
  expect_held_until_the_operator(r.journal.records, killed_at);
  // Failed twice in about 45 runs on a loaded host (2026-11-27: 2.26 and 2.19 mm), never in
  // isolation; the cause is not found. The message carries the cycles from the operator's resume
  // on, for the next person to read.
  std::string after_resume;
  for (std::size_t i = std::size_t(std::max(0LL, killed_at)); i < r.journal.records.size(); ++i) {
    const JournalRecord& q = r.journal.records[i];
    if (q.operator_command == 0 && after_resume.empty()) continue;
    after_resume += "\n  cycle " + std::to_string(q.cycle) + ": state " + std::to_string(q.state) + ", gate " +
                    to_string(GateReason(q.gate_reason)) + ", sent " + std::to_string(q.command_sent) +
                    ", evaluations " + std::to_string(q.evaluations) + ", registration " +
                    std::to_string(q.registration_ms) + " ms, residual " + std::to_string(q.true_residual_mm) +
                    " mm" + (q.overrun ? ", overrun" : "");
  }
  EXPECT_LT(r.journal.records.back().true_residual_mm, 1.0) << "tracking again after the restart" << after_resume;
}

TEST_F(ServedDeviceFaults, StalledCouchServerHolds) {
  long long stalled_at = -1;
  const LoopRun r = run_served("modbus", [&](OperatorClient& op, ServedDevice&) {
    stalled_at = tracking_cycle(op, 20);
    OperatorClient device_control(sockets_.path() / "device.ctl", sockets_.path() / "device-client.sock");
    EXPECT_EQ(device_control.ask("fault no-reply:4").rfind("injected", 0), 0u);
    EXPECT_FALSE(op.wait_for_safe(30s).empty()) << "held by the stall";
    EXPECT_TRUE(op.bring_back_to_track(60s));
  });
  ASSERT_GE(stalled_at, 20);
  expect_held_until_the_operator(r.journal.records, stalled_at);
}

TEST_F(ServedDeviceFaults, UnpluggedRobotBridgeHolds) {
  long long unplugged_at = -1;
  const LoopRun r = run_served("can", [&](OperatorClient& op, ServedDevice&) {
    unplugged_at = tracking_cycle(op, 20);
    OperatorClient device_control(sockets_.path() / "device.ctl", sockets_.path() / "device-client.sock");
    EXPECT_EQ(device_control.ask("fault unplug").rfind("injected", 0), 0u);
    // The driver links again to a robot that has just booted: held until the operator.
    EXPECT_FALSE(op.wait_for_safe(30s).empty()) << "held by the unplug";
    EXPECT_TRUE(op.bring_back_to_track(60s));
  });
  ASSERT_GE(unplugged_at, 20);
  expect_held_until_the_operator(r.journal.records, unplugged_at);
}

// GigE detectors served by `lftrack serve detectors` (two fake GigE Vision cameras, one per
// detector, on two local addresses) and a couch served by `lftrack serve couch`: the loop tracks
// through both protocols; the detector server's cameras power-cycled (off a second) hold the loop
// within a cycle of the frames stopping, the driver reopens the cameras off the cycle, frames
// resume (the gap journaled as cycles without a pair), and only the operator resumes tracking.
TEST_F(ServedDeviceFaults, PowerCycledGigeDetectorsHoldAndTheirFramesResume) {
  const std::vector<std::string> addresses = sim::local_ipv4_addresses();
  if (addresses.size() < 2)
    GTEST_SKIP() << "one GigE camera per detector needs two local IPv4 addresses; this host has " << addresses.size();
  test::GigeHostLock gige_tests_one_at_a_time;
  real_clock_ = true;
  const std::filesystem::path dir = sockets_.path();
  // The servers' scene: the fixture's small scene, as a file.
  std::ofstream(dir / "room.yaml") << small_scene_text(kBreathing, kLightFieldFrames);
  device_ = serve("modbus", dir);
  test::ChildProcess detectors({LFTRACK_BIN_PATH, "-q", "serve", "detectors", "--scene", (dir / "room.yaml").string(),
                                "--room", (dir / "room.link").string(), "--address", addresses[0], "--address",
                                addresses[1], "--lf-dir", small_scene_light_field_dir().string(), "--control",
                                (dir / "detectors.ctl").string(), "--threads", "1"});
  const std::optional<std::string> listening = detectors.read_line(120s);
  ASSERT_TRUE(listening.has_value()) << "the detector server started";
  if (listening->find("gige") == std::string::npos) GTEST_SKIP() << *listening;
  edit_scene_ = [&](Scene& s) {
    use_served(s, "modbus", dir, device_.port);
    s.sim.couch_link.clear();
    for (std::size_t i = 0; i < s.detectors.size(); ++i) {
      s.detectors[i].frames.kind = "gige";
      s.detectors[i].frames.device = addresses[i];
      s.detectors[i].simulator_calibration = true;
    }
    s.loop.acquire_timeout_ms = 60;  // the server renders each pair when triggered
    s.loop.registration_budget_ms = 35;
  };
  LoopSessionOptions options;
  options.devices = SessionDevices::kScene;
  options.control_socket = dir / "control.sock";
  long long cycled_at = -1, stopped_at = -1;
  bool tracked_again = false, tracked_after_stop = false;
  const LoopRun r = run_loop(kBreathing, 0, options, kLightFieldFrames, [&](LoopSession& session) {
    return std::thread([&] {
      OperatorClient op(options.control_socket, dir / "operator.sock");
      cycled_at = tracking_cycle(op, 20);
      OperatorClient detector_control(dir / "detectors.ctl", dir / "detectors-client.sock");
      // The server answers once the cameras are back (off for 10 x 100 ms).
      EXPECT_EQ(detector_control.ask("fault power-cycle:10", 60).rfind("injected", 0), 0u);
      EXPECT_FALSE(op.wait_for_safe(30s).empty()) << "held by the power cycle";
      // The driver reopens the cameras; a resume before that holds again.
      tracked_again = op.bring_back_to_track(60s);
      // Detectors whose frames stop for longer (`fault stop`: the cameras go and stay gone
      // until `fault start`): held again, and back only by the operator once frames come.
      stopped_at = tracking_cycle(op, cycled_at + 30);
      EXPECT_EQ(detector_control.ask("fault stop", 10).rfind("injected", 0), 0u);
      const std::string stopped = op.wait_for_safe(30s);
      EXPECT_FALSE(stopped.empty()) << "held when the frames stopped";
      // Five cycles without frames, journaled as such, before they start again.
      op.wait_for_cycle(OperatorClient::cycle_of(stopped) + 6, 60s);
      EXPECT_EQ(detector_control.ask("fault start", 10).rfind("injected", 0), 0u);
      tracked_after_stop = op.bring_back_to_track(60s);
      const long long back_at = OperatorClient::cycle_of(op.ask("status"));
      if (tracked_after_stop && back_at >= 0) op.wait_for_cycle(back_at + 5, 30s);  // frames flow
      session.request_stop();
    });
  });
  ASSERT_GE(cycled_at, 20);
  EXPECT_TRUE(tracked_again) << "frames resumed and the operator resumed";
  const std::size_t out = expect_held_until_the_operator(r.journal.records, cycled_at);
  EXPECT_GE(cycles_without_a_pair(r.journal.records, out), 1u)
      << "the gap is journaled as cycles without a pair" << held_stretch(r.journal.records, out);
  ASSERT_GT(stopped_at, cycled_at);
  EXPECT_TRUE(tracked_after_stop) << "frames started again and the operator resumed";
  const std::size_t out_stopped = expect_held_until_the_operator(r.journal.records, stopped_at);
  EXPECT_GE(cycles_without_a_pair(r.journal.records, out_stopped), 5u)
      << "a second without frames is journaled as cycles without a pair" << held_stretch(r.journal.records, out_stopped);
  EXPECT_NE(r.journal.records.back().frame_sequence[0], 0u) << "frames resumed";
}

// `lftrack serve detectors` on its default addresses (127.0.0.1 and 127.0.0.2), fed malformed GVCP
// datagrams of many shapes by a raw UDP client (one killed the server once: Aravis's fake camera
// read and wrote where a datagram's length fields said): each camera still answers a well-formed
// read, and the server stops on request with its summary.
TEST_F(ServedDeviceFaults, MalformedGvcpDatagramsLeaveTheDetectorServerServing) {
  test::GigeHostLock gige_tests_one_at_a_time;
  for (const char* address : {"127.0.0.1", "127.0.0.2"})
    if (!sim::gvcp_port_free(address))
      GTEST_SKIP() << "another program holds UDP port 3956 (GVCP) on " << address;
  const std::filesystem::path dir = sockets_.path();
  std::ofstream(dir / "room.yaml") << small_scene_text(kBreathing, kLightFieldFrames);
  test::ChildProcess detectors({LFTRACK_BIN_PATH, "-q", "serve", "detectors", "--scene",
                                (dir / "room.yaml").string(), "--lf-dir",
                                small_scene_light_field_dir().string(), "--control",
                                (dir / "detectors.ctl").string(), "--threads", "1"});
  const std::optional<std::string> listening = detectors.read_line(120s);
  ASSERT_TRUE(listening.has_value()) << "the detector server started";
  EXPECT_NE(listening->find("gige 127.0.0.1 (256 x 256), 127.0.0.2 (256 x 256)"), std::string::npos)
      << *listening;
  const std::vector<std::vector<std::uint8_t>> malformed = test::malformed_gvcp_datagrams();
  for (const char* address : {"127.0.0.1", "127.0.0.2"}) {
    test::GvcpClient client(address);
    // Each followed by a read of the camera's test register (0x1F0 holds 0x12345678).
    for (std::size_t i = 0; i < malformed.size(); ++i) {
      EXPECT_TRUE(client.send(malformed[i])) << address << ": " << malformed[i].size() << " bytes";
      ASSERT_EQ(client.read_register(0x1F0, std::uint16_t(i), 5s).value_or(0), 0x12345678u)
          << address << " no longer answers after datagram " << i << " (" << malformed[i].size() << " bytes)";
    }
  }
  OperatorClient control(dir / "detectors.ctl", dir / "detectors-client.sock");
  EXPECT_EQ(control.ask("stop", 10).rfind("stopping", 0), 0u);
  const std::optional<std::string> summary = detectors.read_line(30s);
  ASSERT_TRUE(summary.has_value()) << "the server's summary";
  EXPECT_NE(summary->find("\"frames_served\""), std::string::npos) << *summary;
  EXPECT_EQ(detectors.wait(10s), 0) << "a clean exit, not a crash";
}

// The loopback devices of the v4l2loopback module on this host, found by their driver's name.
std::vector<std::string> v4l2_loopback_devices() {
  std::vector<std::string> found;
  for (int n = 0; n < 64; ++n) {
    const std::string path = "/dev/video" + std::to_string(n);
    const int fd = ::open(path.c_str(), O_RDWR | O_CLOEXEC);
    if (fd < 0) continue;
    v4l2_capability cap{};
    if (::ioctl(fd, VIDIOC_QUERYCAP, &cap) == 0 &&
        std::strncmp(reinterpret_cast<const char*>(cap.driver), "v4l2 loopback", 13) == 0)
      found.push_back(path);
    ::close(fd);
  }
  return found;
}

// `serve detectors --v4l2loopback` writes the frames into loopback devices and the loop reads
// them through the kernel's V4L2 capture path (drivers/v4l2_detector.hpp), the couch served as
// well. Skips where the module is not loaded (this machine's kernel has none).
TEST_F(ServedDeviceFaults, FramesThroughV4l2LoopbackAreTracked) {
  const std::vector<std::string> devices = v4l2_loopback_devices();
  if (devices.size() < 2)
    GTEST_SKIP() << "needs two v4l2loopback devices: sudo apt install v4l2loopback-dkms && sudo modprobe v4l2loopback "
                    "devices=2 exclusive_caps=0 (found "
                 << devices.size() << ")";
  real_clock_ = true;
  const std::filesystem::path dir = sockets_.path();
  std::ofstream(dir / "room.yaml") << small_scene_text(kBreathing, kLightFieldFrames);
  device_ = serve("modbus", dir);
  test::ChildProcess detectors({LFTRACK_BIN_PATH, "-q", "serve", "detectors", "--scene", (dir / "room.yaml").string(),
                                "--room", (dir / "room.link").string(), "--v4l2loopback", devices[0],
                                "--v4l2loopback", devices[1], "--lf-dir", small_scene_light_field_dir().string()});
  const std::optional<std::string> listening = detectors.read_line(120s);
  ASSERT_TRUE(listening.has_value() && listening->find("v4l2loopback") != std::string::npos);
  edit_scene_ = [&](Scene& s) {
    use_served(s, "modbus", dir, device_.port);
    s.sim.couch_link.clear();
    for (std::size_t i = 0; i < s.detectors.size(); ++i) {
      s.detectors[i].frames.kind = "v4l2";
      s.detectors[i].frames.device = devices[i];
      s.detectors[i].simulator_calibration = true;
    }
    s.loop.acquire_timeout_ms = 60;
    s.loop.registration_budget_ms = 35;
  };
  LoopSessionOptions options;
  options.devices = SessionDevices::kScene;
  const LoopRun r = run_loop(kBreathing, 60, options);
  EXPECT_GE(r.summary.states[std::size_t(TrackingState::kTrack)], 50) << to_json(r.summary).dump();
}

}  // namespace
}  // namespace lftrack::session
