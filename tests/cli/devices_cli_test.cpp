// `lftrack serve ...` and `lftrack sim --hil ...` as a user runs them: what a device server says
// at start, and what a hardware-in-the-loop run reports of its link.

#include <gtest/gtest.h>

#include <fstream>
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

// A couch server other hosts can reach gives the warning the monitor page gives (listen_address.hpp:
// reachable_warning); on loopback it gives none.
TEST(ServeCli, ACouchServerOnEveryInterfaceWarnsThatOtherHostsCanMoveTheCouch) {
  std::string out;
  const Status wide = run_process(
      {LFTRACK_BIN_PATH, "serve", "couch", "--modbus", "tcp:0.0.0.0:0", "--duration", "0.2"}, &out);
  ASSERT_TRUE(wide.ok()) << wide.message() << "\n" << out;
  EXPECT_NE(out.find("the modbus couch server listens on 0.0.0.0:"), std::string::npos) << out;
  EXPECT_NE(out.find("(every interface): other hosts can reach it and move the couch"), std::string::npos)
      << out;
  const Status local = run_process(
      {LFTRACK_BIN_PATH, "serve", "couch", "--modbus", "tcp:127.0.0.1:0", "--duration", "0.2"}, &out);
  ASSERT_TRUE(local.ok()) << local.message() << "\n" << out;
  EXPECT_EQ(out.find("other hosts can reach it"), std::string::npos) << "no warning on loopback: " << out;
}

// The CAN block of `sim --hil can --json` carries the link's disconnects and reconnects (as the
// Modbus block does) and the faults seen during the run beside the faults at its end.
TEST(SimHilCli, TheCanBlockReportsTheLinkAndTheFaultsSeen) {
  test::TempDir dir;
  std::string scene = test::tiny_field_phantom_scene_text();
  std::ofstream(dir.path() / "sim.yaml") << scene;
  std::string out;
  const Status s = run_process(
      {LFTRACK_BIN_PATH, "-q", "sim", "--scene", (dir.path() / "sim.yaml").string(), "--fast", "--cycles",
       "3", "--lf-dir", (dir.path() / "lf").string(), "--journal", "", "--hil", "can", "--json"},
      &out);
  ASSERT_TRUE(s.ok()) << s.message() << "\n" << out;
  const nlohmann::json j = nlohmann::json::parse(out.substr(out.find("{\n")), nullptr, false);
  ASSERT_FALSE(j.is_discarded()) << out;
  ASSERT_TRUE(j.contains("hil")) << out;
  const nlohmann::json& hil = j["hil"];
  EXPECT_EQ(hil.value("protocol", ""), "can");
  for (const char* key : {"disconnects", "reconnects"}) {
    ASSERT_TRUE(hil.contains(key) && hil[key].is_number_integer()) << key << ": " << hil.dump();
    EXPECT_EQ(hil[key].get<int>(), 0) << key;
  }
  EXPECT_EQ(hil.value("faults", ""), "none");
  EXPECT_EQ(hil.value("faults_seen", ""), "none") << hil.dump();
}

// An actuator whose largest allowed move (safety.max_total_mm at the scene's speed, after its
// latency) takes longer than the beam may wait is warned of at start, whatever its type: the
// scene's dynamics are what the host assumes of a Modbus couch or a CAN robot as of the virtual
// couch (drivers/actuator_dynamics.hpp). At the built-in scene's speed nothing is said.
TEST(SimHilCli, AnActuatorTooSlowForTheBeamsWaitIsWarnedOfWhateverItsType) {
  test::TempDir dir;
  std::string scene = test::tiny_field_phantom_scene_text();
  std::ofstream(dir.path() / "quick.yaml") << scene;
  const std::string speed = "  max_speed_mm_s: 40\n";
  ASSERT_NE(scene.find(speed), std::string::npos);
  scene.replace(scene.find(speed), speed.size(), "  max_speed_mm_s: 0.5\n");
  std::ofstream(dir.path() / "slow.yaml") << scene;
  const std::string warning = "takes 20.1 s, not less than safety.max_beam_withheld_s (10 s)";
  for (const char* hil : {"", "modbus", "can"}) {
    // The quick scene once (the virtual couch's): the warning's absence does not depend on the type.
    for (const char* file : {"slow.yaml", *hil == '\0' ? "quick.yaml" : nullptr}) {
      if (file == nullptr) continue;
      std::vector<std::string> args = {LFTRACK_BIN_PATH,
                                       "sim",
                                       "--scene",
                                       (dir.path() / file).string(),
                                       "--fast",
                                       "--cycles",
                                       "2",
                                       "--lf-dir",
                                       (dir.path() / "lf").string(),
                                       "--journal",
                                       ""};
      if (*hil != '\0') args.insert(args.end(), {"--hil", hil});
      std::string out;
      const Status s = run_process(args, &out);
      ASSERT_TRUE(s.ok()) << s.message() << "\n" << out;
      if (std::string(file) == "slow.yaml")
        EXPECT_NE(out.find(warning), std::string::npos) << (*hil ? hil : "virtual") << ":\n" << out;
      else
        EXPECT_EQ(out.find("max_beam_withheld_s"), std::string::npos) << (*hil ? hil : "virtual") << ":\n"
                                                                      << out;
    }
  }
}

}  // namespace
}  // namespace lftrack::session
