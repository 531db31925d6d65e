// The calibrated couch (calibrated_couch.hpp): corrections in room terms through the couch
// calibration into couch moves, and read-backs back into room terms. (The first test moved from
// the closed-loop couch calibration test.)

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "lftrack/calib/couch_calibration.hpp"
#include "lftrack/host/calibrated_couch.hpp"

namespace lftrack::host {
namespace {

TEST(CalibratedCouch, TheIdealCalibrationPassesCorrectionsThroughUnchanged) {
  struct Sink final : drivers::Actuator {
    Status open() override { return {}; }
    drivers::DeviceStatus command(const tracking::Vector6d& c, drivers::Deadline) override {
      last = c;
      return drivers::DeviceStatus::kOk;
    }
    drivers::DeviceStatus readback(drivers::ActuatorState* s, drivers::Deadline) override {
      s->position = last;
      s->target = last;
      return drivers::DeviceStatus::kOk;
    }
    void hold() override {}
    void close() override {}
    tracking::Vector6d last = tracking::Vector6d::Zero();
  } sink;
  const Eigen::Vector3d origin(3, -4, 12);
  Eigen::Isometry3d ideal = Eigen::Isometry3d::Identity();
  ideal.translation() = origin;
  CalibratedCouch couch(&sink, ideal, origin);
  tracking::Vector6d c;
  c << 1.5, -2, 0.7, 0.01, -0.02, 0.015;
  ASSERT_EQ(couch.command(c, drivers::Deadline::max()), drivers::DeviceStatus::kOk);
  EXPECT_LT((sink.last - c).norm(), 1e-12);
  drivers::ActuatorState state;
  ASSERT_EQ(couch.readback(&state, drivers::Deadline::max()), drivers::DeviceStatus::kOk);
  EXPECT_LT((state.position - c).norm(), 1e-12);
  // A mounted couch: the move it is sent produces the room motion asked for.
  const Eigen::Isometry3d x = [] {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.linear() = tracking::rotation_exp(Eigen::Vector3d(0.02, -0.01, 0.03));
    t.translation() = Eigen::Vector3d(5, -30, 200);
    return t;
  }();
  CalibratedCouch mounted(&sink, x, origin);
  ASSERT_EQ(mounted.command(c, drivers::Deadline::max()), drivers::DeviceStatus::kOk);
  const Eigen::Isometry3d wanted =
      tracking::apply_delta(tracking::Pose::Identity(), tracking::PoseDelta::from_vector(c), origin);
  EXPECT_TRUE(calib::room_motion_of_couch(x, sink.last).isApprox(wanted, 1e-12));
  ASSERT_EQ(mounted.readback(&state, drivers::Deadline::max()), drivers::DeviceStatus::kOk);
  EXPECT_LT((state.position - c).norm(), 1e-9) << "read-back comes back in room terms";
  // A non-finite correction is refused: nothing is sent.
  sink.last.setZero();
  c(0) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(mounted.command(c, drivers::Deadline::max()), drivers::DeviceStatus::kRefused);
  EXPECT_TRUE(sink.last.isZero());
}

// A couch whose target is the sum of the moves it was sent, along its own axes, as the virtual
// couch's and the drivers' are.
struct AddingCouch final : drivers::Actuator {
  Status open() override { return {}; }
  drivers::DeviceStatus command(const tracking::Vector6d& move, drivers::Deadline) override {
    target += move;
    return drivers::DeviceStatus::kOk;
  }
  drivers::DeviceStatus readback(drivers::ActuatorState* s, drivers::Deadline) override {
    s->position = s->target = target;
    return drivers::DeviceStatus::kOk;
  }
  void hold() override {}
  void close() override {}
  tracking::Vector6d target = tracking::Vector6d::Zero();
};

// Through a couch mounted 1 degree off about each axis with its centre 200 mm away, hundreds of
// breathing-sized corrections with rotations: the read-back target in room terms stays the sum of
// the corrections sent (what the loop's read-back check compares), with or without a read-back
// between commands. Converting each step on its own drifted by a second-order error that held a
// correct loop after 118 cycles (CI at 8339f2b).
TEST(CalibratedCouch, TheReadBackTargetIsTheSumOfTheCorrectionsSent) {
  Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
  x.linear() = tracking::rotation_exp(Eigen::Vector3d(1, 1, 1) * tracking::deg_to_rad(1.0));
  x.translation() = Eigen::Vector3d(5, -30, 200);
  AddingCouch couch;
  CalibratedCouch calibrated(&couch, x, Eigen::Vector3d(0, 0, 0));
  tracking::Vector6d sent = tracking::Vector6d::Zero();
  double worst = 0;
  for (int k = 0; k < 400; ++k) {
    tracking::Vector6d step;
    step << 0.6 * std::sin(0.3 * k), 0.4 * std::cos(0.2 * k), 0.8 * std::sin(0.15 * k + 1), 0.004 * std::cos(0.1 * k),
        -0.003 * std::sin(0.25 * k), 0.005 * std::sin(0.05 * k);
    ASSERT_EQ(calibrated.command(step, drivers::Deadline::max()), drivers::DeviceStatus::kOk);
    sent += step;
    if (k % 3 == 0) continue;  // sometimes two commands without a read-back between them
    drivers::ActuatorState state;
    ASSERT_EQ(calibrated.readback(&state, drivers::Deadline::max()), drivers::DeviceStatus::kOk);
    worst = std::max(worst, (state.target - sent).cwiseAbs().maxCoeff());
  }
  EXPECT_LT(worst, 1e-9) << "read-back target against the corrections sent";
}

}  // namespace
}  // namespace lftrack::host
