// The simulated room of a scene (room_simulator.hpp): the couch mounted as the scene says, for the
// session's room and the served detectors' alike (`lftrack serve detectors` once left the
// mounting out, so a mounted couch moved its detectors' patient about the wrong axes).

#include "lftrack/sim_devices/room_simulator.hpp"

#include <gtest/gtest.h>

#include "lftrack/session/loop_session.hpp"
#include "lftrack/tracking/thread_pool.hpp"

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

}  // namespace
}  // namespace lftrack::sim_devices
