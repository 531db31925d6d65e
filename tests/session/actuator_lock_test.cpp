// One program at a time drives a couch (actuator_lock.hpp): another process's lock refuses this
// one with the holder named; within a process the lock is shared; a holder that crashes leaves no
// stale lock.

#include "lftrack/session/actuator_lock.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>

#include "actuator_lock_holder.hpp"
#include "cli_text.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

// Lock files in a folder of the test's own (the forked holders inherit it).
class ActuatorLockTest : public ::testing::Test {
 protected:
  void SetUp() override { lock_dir_.emplace(kTestLockDirVariable, dir_.path().string()); }
  void TearDown() override { lock_dir_.reset(); }

  static Scene modbus_couch(int port) {
    Scene scene;
    scene.actuator.type = "modbus";
    scene.actuator.modbus.host = "127.0.0.1";
    scene.actuator.modbus.port = port;
    return scene;
  }

  test::TempDir dir_;
  std::optional<test::ScopedEnvironment> lock_dir_;
};

TEST_F(ActuatorLockTest, AnotherProcessIsRefusedWithTheHolderNamed) {
  const Scene scene = modbus_couch(1502);
  test::ActuatorLockHolder other(scene);
  ASSERT_TRUE(other.held());
  auto refused = ActuatorLock::acquire(scene);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kFailedPrecondition);
  const std::string& why = refused.status().message();
  EXPECT_NE(why.find("driven by another lftrack"), std::string::npos) << why;
  EXPECT_NE(why.find("pid " + std::to_string(other.pid())), std::string::npos) << "names the holder: " << why;
  EXPECT_NE(why.find("127.0.0.1"), std::string::npos) << "names the couch: " << why;
  EXPECT_NE(why.find(ActuatorLock::lock_path(scene)), std::string::npos) << "names the lock: " << why;

  // Another couch is another lock.
  EXPECT_TRUE(ActuatorLock::acquire(modbus_couch(1503)).ok());
  // Let go, the couch is this process's.
  other.end();
  auto mine = ActuatorLock::acquire(scene);
  EXPECT_TRUE(mine.ok()) << mine.status().message();
}

TEST_F(ActuatorLockTest, AHolderThatCrashesLeavesNoStaleLock) {
  const Scene scene = modbus_couch(1504);
  test::ActuatorLockHolder crashed(scene);
  ASSERT_TRUE(crashed.held());
  ASSERT_FALSE(ActuatorLock::acquire(scene).ok());
  crashed.kill();
  EXPECT_TRUE(std::filesystem::exists(ActuatorLock::lock_path(scene))) << "its file stays, reused";
  auto after = ActuatorLock::acquire(scene);
  EXPECT_TRUE(after.ok()) << after.status().message();
}

TEST_F(ActuatorLockTest, IsSharedWithinAProcessAndReleasedWithItsLastHolder) {
  const Scene scene = modbus_couch(1505);
  auto first = ActuatorLock::acquire(scene);
  ASSERT_TRUE(first.ok()) << first.status().message();
  auto second = ActuatorLock::acquire(scene);  // a QA's loop session under the QA's lock
  ASSERT_TRUE(second.ok()) << second.status().message();
  EXPECT_EQ(first->get(), second->get());
  {
    test::ActuatorLockHolder other(scene);
    EXPECT_FALSE(other.held()) << "held by this process";
  }
  first->reset();
  {
    test::ActuatorLockHolder other(scene);
    EXPECT_FALSE(other.held()) << "still held by the second";
  }
  second->reset();
  test::ActuatorLockHolder other(scene);
  EXPECT_TRUE(other.held()) << "released with its last holder";
}

TEST_F(ActuatorLockTest, OnlyADeviceHasOneAndItsFileSaysWhichCouch) {
  Scene scene;
  scene.actuator.type = "virtual";
  auto refused = ActuatorLock::acquire(scene);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kInvalidArgument);

  const std::string path = ActuatorLock::lock_path(modbus_couch(1506));
  EXPECT_EQ(std::filesystem::path(path).parent_path(), dir_.path()) << "in LFTRACK_TEST_LOCK_DIR";
  const std::string name = std::filesystem::path(path).filename().string();
  EXPECT_NE(name.find("modbus"), std::string::npos) << name;
  EXPECT_NE(name.find("127.0.0.1"), std::string::npos) << name;
  EXPECT_NE(name.find("1506"), std::string::npos) << name;
  EXPECT_NE(ActuatorLock::lock_path(modbus_couch(1507)), path);
  Scene can;
  can.actuator.type = "can";
  can.actuator.can.interface = "../../etc/passwd";
  EXPECT_EQ(std::filesystem::path(ActuatorLock::lock_path(can)).parent_path(), dir_.path())
      << "a name's slashes never leave the lock folder";
}

// A lock file another user made: opened without O_CREAT (the kernel's protected_regular refuses
// O_CREAT on another user's file in a sticky folder such as /run/lock).
TEST_F(ActuatorLockTest, AnExistingLockFileIsReused) {
  const Scene scene = modbus_couch(1508);
  const std::string path = ActuatorLock::lock_path(scene);
  {
    std::FILE* f = std::fopen(path.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs("pid 1: an old holder\n", f);
    std::fclose(f);
  }
  auto lock = ActuatorLock::acquire(scene);
  ASSERT_TRUE(lock.ok()) << lock.status().message();
  EXPECT_NE(test::contents(path).find("pid " + std::to_string(::getpid())), std::string::npos)
      << "the holder recorded: " << test::contents(path);
}

// One couch is one lock however a scene spells it: a Modbus host by its numeric address, a serial
// line by its path with links followed; the baud rate and the unit are not the couch.
TEST_F(ActuatorLockTest, OneCouchIsOneLockHoweverItIsSpelled) {
  Scene a = modbus_couch(1509), b = modbus_couch(1509), c = modbus_couch(1509);
  b.actuator.modbus.host = "localhost";
  c.actuator.modbus.host = "127.1";
  c.actuator.modbus.unit_id = 7;
  EXPECT_EQ(ActuatorLock::lock_path(a), ActuatorLock::lock_path(b));
  EXPECT_EQ(ActuatorLock::lock_path(a), ActuatorLock::lock_path(c));
  test::ActuatorLockHolder other(b);
  ASSERT_TRUE(other.held());
  EXPECT_FALSE(ActuatorLock::acquire(c).ok()) << "127.1 is localhost's couch";

  const std::filesystem::path line = dir_.path() / "ttyUSB0", link = dir_.path() / "couch-serial";
  std::FILE* f = std::fopen(line.c_str(), "w");
  ASSERT_NE(f, nullptr);
  std::fclose(f);
  std::filesystem::create_symlink(line, link);
  Scene serial_a, serial_b;
  for (Scene* s : {&serial_a, &serial_b}) {
    s->actuator.type = "modbus";
    s->actuator.modbus.transport = drivers::ModbusCouchOptions::Transport::kRtu;
  }
  serial_a.actuator.modbus.serial_device = line.string();
  serial_a.actuator.modbus.baud = 19200;
  serial_b.actuator.modbus.serial_device = link.string();
  serial_b.actuator.modbus.baud = 115200;
  EXPECT_EQ(ActuatorLock::lock_path(serial_a), ActuatorLock::lock_path(serial_b));
}

// A relative lock folder would be another file in each program's working folder: refused.
TEST_F(ActuatorLockTest, ARelativeLockFolderIsRefused) {
  test::ScopedEnvironment relative(kTestLockDirVariable, "locks");
  auto refused = ActuatorLock::acquire(modbus_couch(1510));
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("not an absolute path"), std::string::npos)
      << refused.status().message();
}

}  // namespace
}  // namespace lftrack::session
