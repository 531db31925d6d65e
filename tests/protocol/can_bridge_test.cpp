// The CAN robot driver through a bridge socket (`lftrack serve robot`; drivers/can_robot.hpp
// bridge_path): it links, commands and reads back; an unplugged bridge is a disconnection, and
// the link made again is a restarted robot that moves nothing until a hold; a second
// controller is turned away; the bridge's socket never replaces a file.

#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <thread>

#include "lftrack/drivers/can_robot.hpp"
#include "lftrack/sim/can_bridge_server.hpp"
#include "lftrack/sim/served_couch.hpp"
#include "test_data.hpp"

namespace lftrack {
namespace {

using drivers::DeviceStatus;
using namespace std::chrono_literals;

drivers::Deadline in(std::chrono::milliseconds ms) {
  return std::chrono::steady_clock::now() + ms;
}

// Calls `step` every 5 ms until `done` holds, for up to five seconds (the bridge and the robot
// act on threads of their own, later on a loaded host).
template <class Done, class Step>
void poll_until(Done done, Step step) {
  for (const auto until = std::chrono::steady_clock::now() + 5s; !done() && std::chrono::steady_clock::now() < until;) {
    step();
    std::this_thread::sleep_for(5ms);
  }
}

class CanBridge : public ::testing::Test {
 protected:
  void SetUp() override {
    char name[] = "/tmp/lfcXXXXXX";  // a socket path has at most 107 bytes
    ASSERT_NE(::mkdtemp(name), nullptr);
    dir_ = name;
    auto couch = sim::ServedCouch::start(sim::VirtualCouchSpec{}, "");
    ASSERT_TRUE(couch.ok());
    couch_ = std::move(couch).value();
    auto bridge = sim::CanBridgeServer::start(socket(), couch_.get());
    ASSERT_TRUE(bridge.ok()) << bridge.status().message();
    bridge_ = std::move(bridge).value();
  }
  void TearDown() override {
    bridge_.reset();
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }
  std::filesystem::path socket() const { return dir_ / "robot.sock"; }
  drivers::CanRobotOptions options() const {
    drivers::CanRobotOptions o;
    o.bridge_path = socket().string();
    o.reconnect_interval_s = 0.05;
    return o;
  }

  std::filesystem::path dir_;
  std::unique_ptr<sim::ServedCouch> couch_;
  std::unique_ptr<sim::CanBridgeServer> bridge_;
};

TEST_F(CanBridge, LinksCommandsAndReadsBack) {
  drivers::CanRobot robot(options());
  ASSERT_TRUE(robot.open().ok());
  tracking::Vector6d step = tracking::Vector6d::Zero();
  step[0] = 1.0;
  EXPECT_EQ(robot.command(step, in(200ms)), DeviceStatus::kOk);
  drivers::ActuatorState state;
  EXPECT_EQ(robot.readback(&state, in(200ms)), DeviceStatus::kOk);
  EXPECT_NEAR(state.target[0], 1.0, 1e-3);
  EXPECT_EQ(couch_->commands(), 1);
  // A second controller is turned away while the first is linked.
  drivers::CanRobot other(options());
  other.open().ok();  // it may or may not see a heartbeat before the bridge closes it
  poll_until([&] { return bridge_->refused() >= 1; }, [] {});
  EXPECT_GE(bridge_->refused(), 1);
  EXPECT_EQ(robot.readback(&state, in(200ms)), DeviceStatus::kOk) << "the first link is untouched";
}

TEST_F(CanBridge, AnUnpluggedBridgeDisconnectsAndTheReplugIsARestartedRobot) {
  drivers::CanRobot robot(options());
  ASSERT_TRUE(robot.open().ok());
  drivers::ActuatorState state;
  ASSERT_EQ(robot.readback(&state, in(200ms)), DeviceStatus::kOk);
  bridge_->unplug();
  std::this_thread::sleep_for(20ms);
  EXPECT_EQ(robot.readback(&state, in(100ms)), DeviceStatus::kDisconnected);
  EXPECT_EQ(robot.counters().disconnects, 1);
  // Plugged in again (the bridge accepts again): the driver links from the cycle, and what answers
  // has not seen our commands, so nothing is sent until a hold.
  std::this_thread::sleep_for(100ms);
  tracking::Vector6d step = tracking::Vector6d::Zero();
  step[1] = 0.5;
  DeviceStatus s = robot.command(step, in(100ms));
  EXPECT_NE(s, DeviceStatus::kOk);
  EXPECT_EQ(robot.counters().reconnects, 1);
  EXPECT_NE(robot.faults() & drivers::kCanRobotRestarted, 0u);
  EXPECT_EQ(couch_->commands(), 0) << "nothing moved";
  // Until the linked robot's heartbeats arrive (read back: the driver takes frames in its calls).
  const std::int64_t heartbeats = robot.counters().heartbeats;
  poll_until([&] { return robot.counters().heartbeats >= heartbeats + 2; }, [&] { robot.readback(&state, in(50ms)); });
  ASSERT_GE(robot.counters().heartbeats, heartbeats + 2);
  robot.hold();  // the operator's resume follows a hold
  EXPECT_EQ(robot.command(step, in(200ms)), DeviceStatus::kOk);
  EXPECT_EQ(couch_->commands(), 1);
  EXPECT_EQ(robot.faults(), 0u);
  EXPECT_NE(robot.faults_seen() & drivers::kCanRobotRestarted, 0u) << "still among the faults seen";
  EXPECT_EQ(robot.counters().disconnects, 1);
  EXPECT_EQ(robot.counters().reconnects, 1);
}

TEST(CanBridgeServer, NeverReplacesAFile) {
  char name[] = "/tmp/lfcXXXXXX";
  ASSERT_NE(::mkdtemp(name), nullptr);
  const std::filesystem::path dir = name;
  std::ofstream(dir / "robot.sock") << "a file";
  sim::VirtualCouch couch;
  auto bridge = sim::CanBridgeServer::start(dir / "robot.sock", &couch);
  EXPECT_FALSE(bridge.ok());
  EXPECT_TRUE(std::filesystem::is_regular_file(dir / "robot.sock"));
  std::filesystem::remove(dir / "robot.sock");
  auto first = sim::CanBridgeServer::start(dir / "robot.sock", &couch);
  ASSERT_TRUE(first.ok());
  auto second = sim::CanBridgeServer::start(dir / "robot.sock", &couch);
  EXPECT_FALSE(second.ok()) << "a bridge is listening there";
  first->reset();
  auto stale = sim::CanBridgeServer::start(dir / "robot.sock", &couch);
  EXPECT_TRUE(stale.ok()) << "no socket left: starts";
  stale->reset();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace lftrack
