// `lftrack run`, `replay` and `info` as a user runs them, on what issue 50's outside probe found:
// an unattended operator offered for the treatment room, replays and archived frames that said
// they moved a couch, a start-up check and an `ignore` scene that took real-time priority, and a
// CT without a scene whose ROI was silently the volume centre. Each run is a few cycles of the
// built-in scene with tiny light fields.

#include <gtest/gtest.h>

#include <cctype>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

namespace fs = std::filesystem;

class RunCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    shared_ = new test::TempDir();
    std::ofstream(shared_->path() / "sim.yaml") << scene_text();
  }
  static void TearDownTestSuite() { delete shared_; }

  // The built-in scene with tiny light fields, `from` replaced by `to` where given.
  static std::string scene_text(const std::string& from = "", const std::string& to = "") {
    std::string scene = test::tiny_field_phantom_scene_text();
    if (!from.empty()) {
      for (std::size_t at = scene.find(from); at != std::string::npos; at = scene.find(from, at + to.size()))
        scene.replace(at, from.size(), to);
    }
    return scene;
  }
  static fs::path scene() { return shared_->path() / "sim.yaml"; }
  static std::string lf_dir() { return (shared_->path() / "lf").string(); }

  // `lftrack [-q] COMMAND --scene SCENE --lf-dir LF ARGS...`
  static Status lftrack(const std::string& command, const fs::path& scene_file, const std::vector<std::string>& args,
                        std::string* out, bool quiet = false) {
    std::vector<std::string> argv = {LFTRACK_BIN_PATH};
    if (quiet) argv.push_back("-q");
    argv.insert(argv.end(), {command, "--scene", scene_file.string(), "--lf-dir", lf_dir()});
    argv.insert(argv.end(), args.begin(), args.end());
    return run_process(argv, out);
  }

  // Whether the summary in `out` says no correction was sent ("corrections sent 0", then no digit).
  static bool says_none_sent(const std::string& out) {
    const std::string said = "corrections sent 0";
    const std::size_t at = out.find(said);
    return at != std::string::npos && (at + said.size() == out.size() || !std::isdigit(static_cast<unsigned char>(out[at + said.size()])));
  }

  // The line of `out` that starts with `start` (empty if none).
  static std::string line_starting(const std::string& out, const std::string& start) {
    std::istringstream lines(out);
    for (std::string line; std::getline(lines, line);)
      if (line.rfind(start, 0) == 0) return line;
    return {};
  }

  static inline test::TempDir* shared_ = nullptr;
  test::TempDir dir_;
};

// --hil on a scene with no couch is refused from the scene alone, naming its line, before the CT
// is read (here one that does not exist) or a light field built.
TEST_F(RunCli, HilWithoutACouchIsRefusedBeforeTheCtIsRead) {
  const fs::path none = dir_.path() / "no-couch.yaml";
  std::ofstream(none) << scene_text("type: virtual", "type: none");
  std::string out;
  const Status s = lftrack("sim", none,
                           {"--hil", "modbus", "--fast", "--cycles", "5", "--journal", "", "--ct",
                            (dir_.path() / "absent.nii").string()},
                           &out);
  ASSERT_FALSE(s.ok()) << out;
  EXPECT_NE(out.find("hardware in the loop needs a scene with a couch"), std::string::npos) << out;
  EXPECT_NE(out.find("no-couch.yaml:"), std::string::npos) << "names the scene's line: " << out;
  EXPECT_EQ(out.find("absent.nii"), std::string::npos) << "the CT was never read: " << out;
}

// Only a person ends a HOLD in the room: `run` has no unattended operator to offer (a usage
// error, before anything is loaded); `sim` and `replay` keep it.
TEST_F(RunCli, AutoResumeIsNoOptionOfRun) {
  std::string out;
  const Status s = lftrack("run", scene(), {"--auto-resume", "5", "--rt", "ignore"}, &out);
  EXPECT_NE(s.message().find("(status 512)"), std::string::npos) << s.message() << "\n" << out;
  EXPECT_NE(out.find("--auto-resume"), std::string::npos) << out;
  EXPECT_EQ(out.find("pre-treatment checklist"), std::string::npos) << "refused before the checks: " << out;
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "run", "--help"}, &out).ok()) << out;
  EXPECT_EQ(out.find("--auto-resume"), std::string::npos) << out;
  for (const char* command : {"sim", "replay"}) {
    ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, command, "--help"}, &out).ok()) << out;
    EXPECT_NE(out.find("--auto-resume"), std::string::npos) << command << ": " << out;
  }
}

// A replay moves nothing: its summary says no correction was sent. `run` on archived frames
// cannot drive a real couch (refused at load, with the line); with no actuator it tracks and
// reports, naming the sequence it replays.
TEST_F(RunCli, ArchivedFramesMoveNothingAndSaySo) {
  const fs::path sequence = dir_.path() / "seq";
  std::string out;
  ASSERT_TRUE(
      lftrack("sim", scene(), {"--fast", "--cycles", "20", "--journal", "", "--archive", sequence.string()}, &out, true)
          .ok())
      << out;
  ASSERT_TRUE(
      lftrack("replay", scene(), {"--sequence", sequence.string(), "--fast", "--json", "--journal", ""}, &out, true)
          .ok())
      << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_EQ(j["cycles"].get<int>(), 20);
  EXPECT_EQ(j["commands"].get<int>(), 0) << "nothing is sent in a replay";
  ASSERT_TRUE(lftrack("replay", scene(), {"--sequence", sequence.string(), "--fast", "--journal", ""}, &out, true).ok())
      << out;
  EXPECT_TRUE(says_none_sent(out)) << out;

  const std::string archived = "frames: {type: replay, sequence: " + sequence.string() + "}";
  const fs::path couch = dir_.path() / "archive-couch.yaml";
  std::string couch_text = scene_text("frames: sim", archived);
  couch_text.replace(couch_text.find("  type: virtual\n"), 16,
                     "  type: modbus\n  modbus: {tcp: {host: 127.0.0.1, port: 1}}\n");
  std::ofstream(couch) << couch_text;
  const Status refused = lftrack("run", couch, {"--rt", "ignore", "--journal", ""}, &out);
  EXPECT_NE(refused.message().find("(status 256)"), std::string::npos) << refused.message() << "\n" << out;
  EXPECT_NE(out.find(couch.string() + ":"), std::string::npos) << "at load, with the line: " << out;
  EXPECT_NE(out.find("archived frames cannot move a patient"), std::string::npos) << out;
  EXPECT_EQ(out.find("pre-treatment checklist"), std::string::npos) << out;

  std::string none_text = scene_text("frames: sim", archived);
  none_text.replace(none_text.find("  type: virtual\n"), 16, "  type: none\n");
  const fs::path none = dir_.path() / "archive-none.yaml";
  std::ofstream(none) << none_text;
  ASSERT_TRUE(lftrack("run", none, {"--rt", "ignore", "--journal", ""}, &out).ok()) << out;
  EXPECT_NE(out.find("replaying 20 pairs from " + sequence.string()), std::string::npos) << out;
  EXPECT_TRUE(says_none_sent(out)) << out;
}

// `run` has no simulator (issue 55: it is made in lftrack_cli_loop, which links none, and given
// none): a scene with simulated detectors fails its start-up check, naming `sim --room`, and is
// refused before a cycle runs. `sim --room` runs the same scene as `run` would run a room, with
// the simulator's detectors: the same checklist, the real clock, none of a simulation's options.
TEST_F(RunCli, RunHasNoSimulatorAndSimRoomRunsTheRoom) {
  std::string out;
  ASSERT_TRUE(
      run_process({LFTRACK_BIN_PATH, "-q", "precompute", "--scene", scene().string(), "-o", lf_dir()}, &out)
          .ok())
      << out;
  const Status check = lftrack("run", scene(), {"--check", "--rt", "ignore"}, &out);
  EXPECT_NE(check.message().find("(status 256)"), std::string::npos) << check.message() << "\n" << out;
  EXPECT_NE(out.find("[FAIL] simulated detectors"), std::string::npos) << out;
  EXPECT_NE(out.find("lftrack sim --room runs a room with simulated detectors"), std::string::npos) << out;
  const Status refused = lftrack("run", scene(), {"--cycles", "3", "--rt", "ignore", "--journal", ""}, &out);
  EXPECT_FALSE(refused.ok()) << out;
  EXPECT_NE(out.find("lftrack run refuses to start"), std::string::npos) << out;
  EXPECT_EQ(out.find("TRACK"), std::string::npos) << "no cycle ran: " << out;

  ASSERT_TRUE(lftrack("sim", scene(), {"--room", "--check", "--rt", "ignore"}, &out).ok()) << out;
  EXPECT_NE(out.find("pre-treatment checklist"), std::string::npos) << out;
  EXPECT_EQ(out.find("[FAIL]"), std::string::npos) << out;
  ASSERT_TRUE(lftrack("sim", scene(),
                      {"--room", "--cycles", "3", "--rt", "ignore", "--journal", "", "--json"}, &out, true)
                  .ok())
      << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_EQ(j["cycles"].get<int>(), 3);
  // The real clock's path (an offline run says "not applied (offline run ...)").
  EXPECT_EQ(j["realtime"].get<std::string>().rfind("not applied (--rt ignore)", 0), 0u) << j["realtime"];

  // A room's loop is the room's: no simulated clock, no couch behind a driver of the simulator's
  // making, no unattended operator, no imaging or period but the scene's; --check belongs to a
  // room, and neither flag takes a value that turns it off. Usage errors, before anything loads.
  for (const std::vector<std::string>& args :
       std::vector<std::vector<std::string>>{{"--room", "--fast"},
                                             {"--room", "--hil", "modbus"},
                                             {"--room", "--auto-resume", "5"},
                                             {"--room", "--period-ms", "50"},
                                             {"--room", "--imaging", "every_cycle"},
                                             {"--check"},
                                             {"--room=0", "--check"},
                                             {"--room", "--check=0"},
                                             {"--room", "--check", "--json"}}) {
    const Status usage = lftrack("sim", scene(), args, &out);
    EXPECT_NE(usage.message().find("(status 512)"), std::string::npos)
        << args[0] << " " << args.back() << ": " << out;
    EXPECT_EQ(out.find("pre-treatment checklist"), std::string::npos) << out;
  }
}

// `ignore` applies no real-time set-up at all, and the summary says so; `run --check` applies
// none either (it says whether the set-up could be applied). Asserted on what lftrack reports,
// so the test holds with or without the privileges.
TEST_F(RunCli, IgnoreAndTheStartUpChecksApplyNoRealtimeSetUp) {
  std::string out;
  ASSERT_TRUE(lftrack("sim", scene(), {"--cycles", "2", "--json", "--journal", ""}, &out, true).ok()) << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_EQ(j["realtime"].get<std::string>().rfind("not applied (loop.realtime.mode: ignore)", 0), 0u) << j["realtime"];

  const fs::path enforce = dir_.path() / "enforce.yaml";
  std::ofstream(enforce) << scene_text("    mode: ignore          # a treatment-room host sets enforce and cpus\n",
                                       "    mode: enforce\n    cpus: [0]\n");
  (void)lftrack("run", enforce, {"--check"}, &out);  // other checks may fail; the real-time line is the point
  const std::size_t at = out.find("real-time set-up:");
  ASSERT_NE(at, std::string::npos) << out;
  const std::string line = out.substr(at, out.find('\n', at) - at);
  EXPECT_NE(line.find("nothing applied"), std::string::npos) << out;
  EXPECT_EQ(line.find("memory locked"), std::string::npos) << line;
}

// `info --ct` on the built-in scene, which names no ROI centre for another CT: the ROI and the
// registration origin are the volume centre, and the output says so on both lines.
TEST_F(RunCli, InfoSaysWhenTheRoiAndOriginAreTheVolumeCentre) {
  LFTRACK_REQUIRE_SHARED_DATA(test::totalseg_aorta());
  std::string out;
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "-q", "info", "--ct", test::totalseg_aorta().string()}, &out).ok()) << out;
  EXPECT_NE(line_starting(out, "roi").find("the volume centre"), std::string::npos) << out;
  EXPECT_NE(line_starting(out, "registration").find("the volume centre"), std::string::npos) << out;
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "-q", "info"}, &out).ok()) << out;
  EXPECT_EQ(out.find("volume centre"), std::string::npos) << "the built-in scene names its target: " << out;
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "info", "--help"}, &out).ok()) << out;
  EXPECT_NE(out.find("volume centre"), std::string::npos) << "--help says what --ct alone does: " << out;
}

}  // namespace
}  // namespace lftrack::session
