// The session on the room's own devices (SessionDevices::kScene, `lftrack run`) refuses an
// operator that is no person: in the room a HOLD ends only by a person's decision (issue 50).
// Each case is refused in create(), before any device is opened or any record made.

#include <gtest/gtest.h>

#include <string>

#include "lftrack/sim_devices/room_simulator.hpp"
#include "loop_fixture.hpp"

namespace lftrack::session {

using loop::ScriptedOperator;
namespace {

class RoomSession : public ClosedLoop {
 protected:
  // LoopSession::create on the fixture's scene, edited by edit_scene_, with a journal path that
  // exists only if create() made it.
  Result<std::unique_ptr<LoopSession>> create(LoopSessionOptions options) {
    Scene scene = small_scene(kBreathing, kLightFieldFrames);
    if (edit_scene_) edit_scene_(scene);
    auto prepared = prepare_scene(scene, "", pool_);
    EXPECT_TRUE(prepared.ok()) << prepared.status().message();
    scene_ = std::make_unique<PreparedScene>(std::move(prepared).value());
    options.cycles = 1;
    options.simulated_clock = true;
    options.light_field_dir = shared_light_field_dir(*scene_);
    options.journal = journal();
    return LoopSession::create(*scene_, options, pool_);
  }
  std::filesystem::path journal() const { return dir_.path() / "journal.lfj"; }

  // A Modbus couch nobody serves, seen by the simulated detectors through a room link.
  void use_modbus_couch() {
    edit_scene_ = [this](Scene& s) {
      s.actuator.type = "modbus";
      s.actuator.modbus.host = "127.0.0.1";
      s.actuator.modbus.port = 1;
      s.sim.couch_link = (dir_.path() / "room.link").string();
    };
  }
  // GigE detectors nobody serves, with no actuator.
  void use_gige_detectors() {
    edit_scene_ = [](Scene& s) {
      s.actuator.type = "none";
      for (std::size_t i = 0; i < s.detectors.size(); ++i) {
        s.detectors[i].frames.kind = "gige";
        s.detectors[i].frames.device = "127.0.0." + std::to_string(i + 1);
        s.detectors[i].simulator_calibration = true;
      }
    };
  }

  void expect_refused_as_unattended(const Result<std::unique_ptr<LoopSession>>& session) {
    ASSERT_FALSE(session.ok()) << "created with an unattended operator on the room's devices";
    const std::string& m = session.status().message();
    EXPECT_NE(m.find("unattended"), std::string::npos) << m;
    EXPECT_NE(m.find("person"), std::string::npos) << "says who ends a HOLD: " << m;
    EXPECT_FALSE(std::filesystem::exists(journal())) << "refused before any record was made";
  }
};

TEST_F(RoomSession, AutoResumeOnARealCouchIsRefused) {
  use_modbus_couch();
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.devices = SessionDevices::kScene;
  options.auto_resume_s = 1.0;
  expect_refused_as_unattended(create(options));
}

TEST_F(RoomSession, AutoResumeOnRealDetectorsIsRefused) {
  use_gige_detectors();
  LoopSessionOptions options;  // the room's own devices: no simulator
  options.devices = SessionDevices::kScene;
  options.auto_resume_s = 0.0;
  expect_refused_as_unattended(create(options));
}

TEST_F(RoomSession, AScriptedOperatorHookOnARealCouchIsRefused) {
  use_modbus_couch();
  ScriptedOperator unattended(10);
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.devices = SessionDevices::kScene;
  options.hooks.operator_input = &unattended;
  expect_refused_as_unattended(create(options));
}

// The same options where no device is real: every device's simulated twin, or `run` on a scene
// whose detectors and couch are the simulator's.
TEST_F(RoomSession, AnUnattendedOperatorStaysAllowedWhereNothingIsReal) {
  use_modbus_couch();
  LoopSessionOptions simulated;
  simulated.simulator = sim_devices::room_simulator();
  simulated.auto_resume_s = 1.0;
  {
    auto twins = create(simulated);
    EXPECT_TRUE(twins.ok()) << twins.status().message();
  }
  std::filesystem::remove(journal());
  edit_scene_ = {};
  ScriptedOperator unattended(10);
  LoopSessionOptions scene;
  scene.simulator = sim_devices::room_simulator();
  scene.devices = SessionDevices::kScene;
  scene.auto_resume_s = 1.0;
  scene.hooks.operator_input = &unattended;
  auto virtual_couch = create(scene);
  EXPECT_TRUE(virtual_couch.ok()) << virtual_couch.status().message();
}

// The session holds no simulator code (issue 55): the simulated room is made by the
// RoomSimulator the options name. Without one, whatever needs that room is refused in create(),
// naming what is missing, before a light field is built or a record made.
TEST_F(RoomSession, WithoutASimulatorASimulationIsRefused) {
  LoopSessionOptions options;  // devices: kSimulated, and no simulator
  auto session = create(options);
  ASSERT_FALSE(session.ok()) << "a simulation without the simulator";
  const std::string& m = session.status().message();
  EXPECT_NE(m.find("simulator"), std::string::npos) << m;
  EXPECT_FALSE(std::filesystem::exists(journal())) << "refused before any record was made";
}

TEST_F(RoomSession, WithoutASimulatorTheScenesSimulatedDetectorsAreRefused) {
  use_modbus_couch();  // simulated detectors beside a served couch (sim.couch_link)
  LoopSessionOptions options;
  options.devices = SessionDevices::kScene;
  auto session = create(options);
  ASSERT_FALSE(session.ok()) << "lftrack run on simulated detectors without the simulator";
  const std::string& m = session.status().message();
  EXPECT_NE(m.find("detectors are simulated"), std::string::npos) << m;
  EXPECT_NE(m.find("lftrack sim"), std::string::npos) << "says what to run instead: " << m;
  EXPECT_FALSE(std::filesystem::exists(journal())) << "refused before any record was made";
}

// With the simulator, the session's simulated room is the simulator's (sim_devices' accessors
// reach it); a replay has none.
TEST_F(RoomSession, TheSimulatedRoomIsTheSimulators) {
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  auto session = create(options);
  ASSERT_TRUE(session.ok()) << session.status().message();
  EXPECT_NE((*session)->simulation(), nullptr);
  EXPECT_NE(sim_devices::simulated_room(**session), nullptr);
  EXPECT_EQ(sim_devices::modbus_couch_server(**session), nullptr) << "no hardware in the loop asked for";
  EXPECT_EQ(sim_devices::virtual_robot(**session), nullptr);
}

}  // namespace
}  // namespace lftrack::session
