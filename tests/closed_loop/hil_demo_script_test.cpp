// scripts/hil-demo.sh, as a user runs it, on the fixture's small scene made a room of three
// processes (a Modbus couch, two GigE cameras, the loop): it takes a free port where its old
// fixed one (15020) is held, listens on loopback only, and reports the served frames; a detector
// server that exits at once ends the wait at once.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "gige_host_lock.hpp"
#include "lftrack/sim/gige_fake_detector.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "loop_fixture.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

// A socket bound to 127.0.0.1 or 127.0.0.2 at `port` (TCP listening, or UDP), as another
// program holding it; -1 where it cannot be bound (then something else holds it already).
int hold_port(const char* address, int port, int type) {
  const int fd = ::socket(AF_INET, type | SOCK_CLOEXEC, 0);
  sockaddr_in at{};
  at.sin_family = AF_INET;
  at.sin_port = htons(static_cast<std::uint16_t>(port));
  ::inet_pton(AF_INET, address, &at.sin_addr);
  if (::bind(fd, reinterpret_cast<sockaddr*>(&at), sizeof at) != 0 ||
      (type == SOCK_STREAM && ::listen(fd, 1) != 0)) {
    ::close(fd);
    return -1;
  }
  return fd;
}

std::string read_file(const std::filesystem::path& p) {
  std::ostringstream s;
  s << std::ifstream(p).rdbuf();
  return s.str();
}

class HilDemoScript : public ClosedLoop {
 protected:
  // The fixture's small scene as a room: GigE cameras on 127.0.0.1 and 127.0.0.2, a Modbus couch
  // at 127.0.0.1:15020 (the script's copy takes the port its couch server got), the loop's
  // timing of scenes/room/gige-modbus.yaml.
  std::filesystem::path write_room_scene() {
    std::string text = small_scene_text(kBreathing, kLightFieldFrames);
    const auto swap = [&](const std::string& from, const std::string& to) {
      const std::size_t at = text.find(from);
      ASSERT_NE(at, std::string::npos) << from;
      text.replace(at, from.size(), to);
    };
    swap("    frames: sim\n", "    frames: {type: gige, camera: 127.0.0.1}\n    calibration: simulator\n");
    swap("    frames: sim\n", "    frames: {type: gige, camera: 127.0.0.2}\n    calibration: simulator\n");
    swap("actuator:\n  type: virtual\n",
         "actuator:\n  type: modbus\n  modbus:\n    tcp: {host: 127.0.0.1, port: 15020}\n    "
         "response_timeout_ms: 20\n");
    swap("registration_budget_ms: 50\n  acquire_timeout_ms: 40\n",
         "registration_budget_ms: 35\n  acquire_timeout_ms: 60\n");
    const std::filesystem::path file = dir_.path() / "room.yaml";
    std::ofstream(file) << text;
    return file;
  }

  // Runs the script with `args`; its standard output in *out, its standard error in *err.
  Status run_script(const std::vector<std::string>& args, std::string* out, std::string* err) {
    const std::filesystem::path err_file = dir_.path() / "hil-demo.err";
    std::vector<std::string> argv = {"bash", "-c", "\"$0\" \"$@\" 2>'" + err_file.string() + "'",
                                     std::string(LFTRACK_SOURCE_DIR) + "/scripts/hil-demo.sh"};
    argv.insert(argv.end(), args.begin(), args.end());
    const Status s = run_process(argv, out, {std::string("LFTRACK_BIN=") + LFTRACK_BIN_PATH});
    *err = read_file(err_file);
    return s;
  }

  void SetUp() override {
    for (const char* address : {"127.0.0.1", "127.0.0.2"})
      if (!sim::gvcp_port_free(address))
        GTEST_SKIP() << "another program holds UDP port 3956 (GVCP) on " << address;
  }

  test::GigeHostLock gige_tests_one_at_a_time_;
};

TEST_F(HilDemoScript, TakesAFreePortWhereItsOldOneIsHeldListensOnLoopbackAndReportsTheServedFrames) {
  const std::filesystem::path scene = write_room_scene();
  const std::filesystem::path lf = small_scene_light_field_dir();
  const int held = hold_port("127.0.0.1", 15020, SOCK_STREAM);  // -1: another program holds it already
  std::string out, err;
  const Status s = run_script({"--cycles", "20", "--scene", scene.string(), "--lf-dir", lf.string(), "--out",
                               (dir_.path() / "hil").string()},
                              &out, &err);
  if (held >= 0) ::close(held);
  ASSERT_TRUE(s.ok()) << s.message() << "\n" << err << out;
  EXPECT_NE(err.find("gige 127.0.0.1 (256 x 256), 127.0.0.2 (256 x 256)"), std::string::npos)
      << "both cameras on loopback: " << err;
  const nlohmann::json j = nlohmann::json::parse(out, nullptr, false);
  ASSERT_FALSE(j.is_discarded()) << out;
  EXPECT_EQ(j.value("cycles", 0), 20);
  ASSERT_TRUE(j.contains("hil")) << out;
  const std::string endpoint = j["hil"].value("endpoint", "");
  EXPECT_EQ(endpoint.rfind("modbus tcp 127.0.0.1:", 0), 0u) << endpoint;
  EXPECT_EQ(endpoint.find(":15020 "), std::string::npos) << "not the held port: " << endpoint;
  EXPECT_GT(j["hil"].value("requests", 0), 0);
  ASSERT_TRUE(j.contains("served_frames")) << out;
  EXPECT_GT(j["served_frames"].value("frames_served", 0), 0) << j["served_frames"].dump();
  // The latency chain across the processes (issue 56): every acknowledged command has one; the
  // frames cross a GigE stream and the command a Modbus round trip, neither of which is free.
  ASSERT_TRUE(j["latency_chain_ms"].is_object()) << out;
  const int commands = j["latency_chain_ms"].value("commands", 0);
  EXPECT_GT(commands, 0);
  EXPECT_EQ(commands, j["latency_exposure_to_ack_ms"].value("commands", -1));
  EXPECT_GT(j["latency_chain_ms"]["arrive"]["max"].get<double>(), 0.0) << j["latency_chain_ms"].dump();
  EXPECT_GT(j["latency_chain_ms"]["acknowledge"]["max"].get<double>(), 0.0) << j["latency_chain_ms"].dump();
  std::string table;
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "study", "latency",
                           (dir_.path() / "hil" / "journal-modbus.lfj").string(), "--out",
                           (dir_.path() / "latency").string()},
                          &table)
                  .ok())
      << table;
  EXPECT_NE(table.find(std::to_string(commands) + " commands of "), std::string::npos) << table;
}

TEST_F(HilDemoScript, StopsWaitingAsSoonAsTheDetectorServerExits) {
  const std::filesystem::path scene = write_room_scene();
  const std::filesystem::path lf = small_scene_light_field_dir();
  // The second camera's GVCP port held: the detector server is refused as soon as it binds.
  const int held = hold_port("127.0.0.2", 3956, SOCK_DGRAM);
  ASSERT_GE(held, 0);
  std::string out, err;
  const auto t0 = std::chrono::steady_clock::now();
  const Status s = run_script({"--cycles", "20", "--scene", scene.string(), "--lf-dir", lf.string(), "--out",
                               (dir_.path() / "hil").string()},
                              &out, &err);
  const double took_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ::close(held);
  EXPECT_NE(s.message().find("(status 256)"), std::string::npos) << s.message();
  EXPECT_NE(err.find("cannot listen on 127.0.0.2:3956"), std::string::npos) << err;
  EXPECT_NE(err.find("hil-demo: the detector server exited (status 1) before it listened"), std::string::npos)
      << err;
  EXPECT_LT(took_s, 50) << "the script once waited out 60 s for a server that had gone";
}

}  // namespace
}  // namespace lftrack::session
