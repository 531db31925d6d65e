// The simulated room of a scene (room_simulator.hpp): the couch mounted as the scene says, for the
// session's room and the served detectors' alike (`lftrack serve detectors` once left the
// mounting out, so a mounted couch moved its detectors' patient about the wrong axes).

#include "lftrack/sim_devices/room_simulator.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <optional>
#include <string>

#include "lftrack/session/loop_session.hpp"
#include "lftrack/session/preflight.hpp"
#include "lftrack/sim/room_link.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::sim_devices {

using session::couch_mounting;
using session::CouchMountingSpec;
using session::load_scene;
using session::prepare_scene;

namespace {

TEST(SceneRoomSpec, CarriesTheScenesPoseMotionAndTheCouchsMounting) {
  tracking::ThreadPool pool(2);
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  auto ideal = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(ideal.ok()) << ideal.status().message();
  const sim::SimulatedRoomSpec plain = scene_room_spec(*ideal);
  EXPECT_FALSE(plain.couch_T_room_from_couch) << "no actuator.mounting: the ideal couch";
  EXPECT_TRUE(plain.nominal_T_room_from_ct.isApprox(ideal->nominal_T_room_from_ct));
  EXPECT_TRUE(plain.origin_room_mm.isApprox(ideal->registration_origin_room_mm()));
  EXPECT_EQ(plain.setup_error, scene->motion.setup_error);
  EXPECT_DOUBLE_EQ(plain.couch.latency_s, scene->actuator.dynamics.latency_s);

  CouchMountingSpec mounting;
  mounting.rotation_rad = Eigen::Vector3d(0.0, 0.0, 0.05);
  scene->actuator.mounting = mounting;
  auto mounted = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(mounted.ok()) << mounted.status().message();
  const sim::SimulatedRoomSpec spec = scene_room_spec(*mounted);
  ASSERT_TRUE(spec.couch_T_room_from_couch) << "the mounting reaches the simulated room";
  EXPECT_TRUE(spec.couch_T_room_from_couch->isApprox(couch_mounting(mounting, *mounted)));
  EXPECT_FALSE(spec.couch_T_room_from_couch->linear().isApprox(Eigen::Matrix3d::Identity()));
}

// The room link's item among the start-up checks (room_preflight.cpp), if there is one.
const session::PreflightItem* couch_link_item(const session::PreflightReport& r) {
  for (const session::PreflightItem& item : r.items)
    if (item.what.find("room link") != std::string::npos) return &item;
  return nullptr;
}

// A served couch's room link is checked before a run with simulated detectors beside it: there,
// written, and written lately. A link whose server has stopped (killed, or stalled) would show
// the detectors a patient who never moves with the couch the loop commands.
TEST(RoomPreflight, TheServedCouchsRoomLinkMustBeWrittenLately) {
  tracking::ThreadPool pool(2);
  test::TempDir dir;
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  scene->actuator.type = "modbus";  // a couch nobody serves: only the link is looked at here
  scene->actuator.modbus.host = "127.0.0.1";
  scene->actuator.modbus.port = 1;
  auto p = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(p.ok()) << p.status().message();
  const session::LoopSessionOptions options;
  // `read_back`: where the scene's actuator answered it stands, as its own check reports it.
  auto check = [&](const std::filesystem::path& link,
                   std::optional<tracking::Vector6d> read_back = tracking::Vector6d::Zero()) {
    p->scene.sim.couch_link = link.string();
    session::PreflightReport r;
    r.actuator_position = read_back;
    room_simulator()->preflight(*p, options, &r);
    const session::PreflightItem* item = couch_link_item(r);
    return item != nullptr ? *item : session::PreflightItem{"none", session::CheckResult::kPass, "no item"};
  };
  const std::int64_t now_ns = sim::room_link_now_ns();

  session::PreflightItem missing = check(dir.path() / "absent.link");
  EXPECT_EQ(missing.result, session::CheckResult::kFail) << missing.detail;
  EXPECT_NE(missing.detail.find("lftrack serve couch|robot"), std::string::npos) << missing.detail;
  std::ofstream(dir.path() / "garbage.link") << "not a room link";
  session::PreflightItem garbage = check(dir.path() / "garbage.link");
  EXPECT_EQ(garbage.result, session::CheckResult::kFail) << garbage.detail;
  EXPECT_NE(garbage.detail.find("remove it"), std::string::npos)
      << "no server would replace it: " << garbage.detail;

  auto fresh = sim::RoomLinkWriter::create(dir.path() / "fresh.link");
  ASSERT_TRUE(fresh.ok()) << fresh.status().message();
  session::PreflightItem unwritten = check(dir.path() / "fresh.link");
  EXPECT_EQ(unwritten.result, session::CheckResult::kFail) << unwritten.detail;
  EXPECT_NE(unwritten.detail.find("nothing written yet"), std::string::npos) << unwritten.detail;
  tracking::Vector6d at = tracking::Vector6d::Zero();
  at << 1.5, -2.0, 0.5, 0.01, 0.0, -0.02;
  (*fresh)->publish(at);
  session::PreflightItem written = check(dir.path() / "fresh.link", at);
  EXPECT_EQ(written.result, session::CheckResult::kPass) << written.detail;
  EXPECT_NE(written.detail.find("written by process"), std::string::npos) << written.detail;
  // Another couch's link: its couch stands elsewhere than the scene's actuator answered.
  session::PreflightItem other = check(dir.path() / "fresh.link", tracking::Vector6d::Zero());
  EXPECT_EQ(other.result, session::CheckResult::kFail) << other.detail;
  EXPECT_NE(other.detail.find("another couch's link"), std::string::npos) << other.detail;

  auto stale = sim::RoomLinkWriter::create(dir.path() / "stale.link");
  ASSERT_TRUE(stale.ok()) << stale.status().message();
  (*stale)->publish(tracking::Vector6d::Zero(), now_ns - 5'000'000'000);  // 5 s ago: its server stalled
  session::PreflightItem stalled = check(dir.path() / "stale.link");
  EXPECT_EQ(stalled.result, session::CheckResult::kFail) << stalled.detail;
  EXPECT_NE(stalled.detail.find("its server is stalled"), std::string::npos) << stalled.detail;

  // Stamped ahead of this host's clock (a link left from before a reboot): refused, whoever holds it.
  auto ahead = sim::RoomLinkWriter::create(dir.path() / "ahead.link");
  ASSERT_TRUE(ahead.ok()) << ahead.status().message();
  (*ahead)->publish(tracking::Vector6d::Zero(), now_ns + 1000'000'000'000);
  session::PreflightItem future = check(dir.path() / "ahead.link");
  EXPECT_EQ(future.result, session::CheckResult::kFail) << future.detail;
  EXPECT_NE(future.detail.find("ahead of this host's clock"), std::string::npos) << future.detail;

  // A server that ended, leaving its link (as a killed one does): fresh samples, no writer.
  (*fresh)->publish(at);
  (*fresh)->leave_file();
  fresh->reset();
  EXPECT_FALSE(sim::RoomLinkReader::writer_running(dir.path() / "fresh.link"));
  EXPECT_TRUE(sim::RoomLinkReader::writer_running(dir.path() / "stale.link")) << "its writer still holds it";
  session::PreflightItem ended = check(dir.path() / "fresh.link", at);
  EXPECT_EQ(ended.result, session::CheckResult::kFail) << ended.detail;
  EXPECT_NE(ended.detail.find("no process writes it now"), std::string::npos) << ended.detail;
}

}  // namespace
}  // namespace lftrack::sim_devices
