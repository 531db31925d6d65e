#include "lftrack/sim/virtual_couch.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace lftrack::sim {
namespace {

using drivers::DeviceStatus;
using tracking::Vector6d;

Vector6d along_x(double mm) {
  Vector6d v = Vector6d::Zero();
  v(0) = mm;
  return v;
}

TEST(VirtualCouch, WaitsOutItsLatencyThenMovesAtItsSpeed) {
  VirtualCouchSpec spec;
  spec.latency_s = 0.2;
  spec.max_speed_mm_s = 10;
  VirtualCouch couch(spec);
  ASSERT_EQ(couch.command(along_x(3), {}), DeviceStatus::kOk);
  couch.advance_to(0.19);
  EXPECT_EQ(couch.position()(0), 0.0);
  couch.advance_to(0.3);  // 0.1 s of motion at 10 mm/s
  EXPECT_NEAR(couch.position()(0), 1.0, 1e-9);
  couch.advance_to(1.0);
  EXPECT_NEAR(couch.position()(0), 3.0, 1e-12);
  drivers::ActuatorState state;
  ASSERT_EQ(couch.readback(&state, {}), DeviceStatus::kOk);
  EXPECT_FALSE(state.moving);
  EXPECT_EQ(state.position, couch.position());
}

TEST(VirtualCouch, CommandsAreRelativeToTheLastTargetAndRotationIsRateLimited) {
  VirtualCouchSpec spec;
  spec.latency_s = 0;
  spec.max_speed_deg_s = 2;
  VirtualCouch couch(spec);
  Vector6d turn = Vector6d::Zero();
  turn(5) = tracking::deg_to_rad(1.0);
  couch.command(turn, {});
  couch.command(turn, {});
  couch.advance_to(0.5);
  EXPECT_NEAR(tracking::rad_to_deg(couch.position()(5)), 1.0, 1e-9);
  couch.advance_to(5);
  EXPECT_NEAR(tracking::rad_to_deg(couch.position()(5)), 2.0, 1e-9);
}

TEST(VirtualCouch, RefusesTravelOutsideItsRangeAndNonFiniteCommands) {
  VirtualCouch couch;
  EXPECT_EQ(couch.command(along_x(60), {}), DeviceStatus::kFault);
  EXPECT_EQ(couch.target(), Vector6d::Zero());
  EXPECT_EQ(couch.command(along_x(NAN), {}), DeviceStatus::kFault);
  Vector6d big_turn = Vector6d::Zero();
  big_turn(3) = tracking::deg_to_rad(11);
  EXPECT_EQ(couch.command(big_turn, {}), DeviceStatus::kFault);
}

TEST(VirtualCouch, HoldStopsWhereItIsAndDropsWaitingCommands) {
  VirtualCouchSpec spec;
  spec.latency_s = 0.1;
  spec.max_speed_mm_s = 10;
  VirtualCouch couch(spec);
  couch.command(along_x(5), {});
  couch.advance_to(0.2);  // moved 1 mm
  couch.command(along_x(5), {});  // not in effect yet
  couch.hold();
  const double at_hold = couch.position()(0);
  couch.advance_to(3);
  EXPECT_NEAR(couch.position()(0), at_hold, 1e-12);
  EXPECT_NEAR(at_hold, 1.0, 1e-9);
  // A new command after the hold counts from where it stopped.
  couch.command(along_x(1), {});
  couch.advance_to(5);
  EXPECT_NEAR(couch.position()(0), at_hold + 1, 1e-9);
}

}  // namespace
}  // namespace lftrack::sim
