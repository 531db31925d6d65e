// The simulated room: the couch's commands reach the patient after the couch's latency; a served
// couch's patient is where that couch was at the exposure.
// (Moved from the loop's parts test.)

#include <gtest/gtest.h>

#include <chrono>

#include "lftrack/sim/room_link.hpp"
#include "lftrack/sim/simulated_room.hpp"
#include "test_data.hpp"

namespace lftrack::sim {
namespace {

using tracking::Vector6d;

TEST(SimulatedRoom, CouchThatCancelsTheOffsetLeavesNoResidual) {
  sim::SimulatedRoomSpec spec;
  spec.origin_room_mm = {0, 0, 0};
  spec.setup_error << 2, -1, 3, 0.01, 0.02, -0.01;
  spec.couch.latency_s = 0.1;
  spec.couch.max_speed_mm_s = 1000;
  spec.couch.max_speed_deg_s = 1000;
  sim::SimulatedRoom room(spec);
  room.advance_to_ns(1'000'000'000);  // t = 0
  EXPECT_GT(room.residual_mm(), 3.0);
  const tracking::Pose offset = room.patient_T_room_from_ct();
  const Vector6d cancel =
      tracking::delta_between(offset, spec.nominal_T_room_from_ct, spec.origin_room_mm).as_vector();
  ASSERT_EQ(room.couch_actuator().command(cancel, drivers::Deadline(std::chrono::nanoseconds(1'100'000'000))),
            drivers::DeviceStatus::kOk);
  room.advance_to_ns(1'150'000'000);
  EXPECT_GT(room.residual_mm(), 3.0)
      << "the command was sent at its deadline (t = 0.1 s) and waits out the latency";
  room.advance_to_ns(1'300'000'000);
  EXPECT_LT(room.residual_mm(), 1e-9);
}

// The target residual is the set-up error itself about the registration origin, per room axis
// (the patient offset is a delta about that origin), and zero once the couch has cancelled it.
TEST(SimulatedRoom, TheTargetResidualIsThePatientsOffsetAtTheOriginPerAxis) {
  sim::SimulatedRoomSpec spec;
  spec.origin_room_mm = {10, -20, 5};
  spec.setup_error << 2, -1, 3, 0.01, 0.02, -0.01;
  spec.couch.latency_s = 0;
  spec.couch.max_speed_mm_s = 1000;
  spec.couch.max_speed_deg_s = 1000;
  sim::SimulatedRoom room(spec);
  room.advance_to_ns(1'000'000'000);
  const Vector6d before = room.target_residual();
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(before(i), spec.setup_error(i), 1e-9) << "axis " << i;
  const Vector6d cancel =
      tracking::delta_between(room.patient_T_room_from_ct(), spec.nominal_T_room_from_ct, spec.origin_room_mm)
          .as_vector();
  ASSERT_EQ(room.couch_actuator().command(cancel, drivers::Deadline(std::chrono::nanoseconds(1'000'000'000))),
            drivers::DeviceStatus::kOk);
  room.advance_to_ns(1'200'000'000);
  EXPECT_LT(room.target_residual().norm(), 1e-9);
}

// With a served couch (a room link), a pair exposed at t shows the patient where the couch had
// them at t, not where it has moved them by the time the detector's thread asks (on a loaded host,
// tens of milliseconds later).
TEST(SimulatedRoom, AServedCouchIsSeenWhereItWasAtTheExposure) {
  test::TempDir dir;
  auto writer = RoomLinkWriter::create(dir.path() / "room.link");
  ASSERT_TRUE(writer.ok()) << writer.status().message();
  auto reader = RoomLinkReader::open(dir.path() / "room.link");
  ASSERT_TRUE(reader.ok()) << reader.status().message();
  sim::SimulatedRoomSpec spec;
  spec.origin_room_mm = {0, 0, 0};
  spec.couch_link = std::move(reader).value();
  sim::SimulatedRoom room(spec);
  room.advance_to_ns(1'000'000'000);
  // The couch moves 4 mm along x between 10 and 30 ms after the exposure.
  const Vector6d moved = (Vector6d() << 4, 0, 0, 0, 0, 0).finished();
  (*writer)->publish(Vector6d::Zero(), 1'000'000'000);
  (*writer)->publish(Vector6d::Zero(), 1'010'000'000);
  (*writer)->publish(moved, 1'030'000'000);
  const Eigen::Vector3d at_exposure = room.true_T_room_from_ct_at_exposure(1'000'000'000).translation();
  const Eigen::Vector3d now = room.true_T_room_from_ct().translation();
  EXPECT_NEAR((now - at_exposure).x(), 4.0, 1e-9) << "the newest sample: the couch has moved since";
  EXPECT_NEAR((at_exposure - room.patient_T_room_from_ct().translation()).norm(), 0.0, 1e-9)
      << "at the exposure the couch had not moved yet";
  const Eigen::Vector3d midway = room.true_T_room_from_ct_at_exposure(1'020'000'000).translation();
  EXPECT_NEAR((midway - at_exposure).x(), 2.0, 1e-9) << "halfway through the move";
}

}  // namespace
}  // namespace lftrack::sim
