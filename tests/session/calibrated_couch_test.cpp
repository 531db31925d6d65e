// The calibrated couch (calibrated_couch.hpp): corrections in room terms through the couch
// calibration into couch moves, and read-backs back into room terms. (The first test moved from
// the closed-loop couch calibration test.)

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <limits>

#include "lftrack/calib/couch_calibration.hpp"
#include "lftrack/session/calibrated_couch.hpp"
#include "lftrack/session/calibration_files.hpp"
#include "test_data.hpp"

namespace lftrack::session {
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

// A couch calibration file is the writer's keys with a report the solver could have made: a
// typo, a negative rms or standard deviation, too few moves or a centre metres away is refused
// with the line.
TEST(CouchCalibrationFile, RefusesWhatTheSolverCouldNotHaveWritten) {
  test::TempDir dir;
  const std::string good =
      "couch_calibration:\n"
      "  rotation_deg: [0.5, -0.2, 1.0]\n"
      "  centre_mm: [1, 2, 3]\n"
      "  rms_mm: 0.05\n"
      "  rotation_sd_deg: [0.01, 0.01, 0.01]\n"
      "  centre_sd_mm: [0.1, 0.1, 0.1]\n"
      "  centre_determined: true\n"
      "  moves: 8\n"
      "  source: a test\n";
  const auto file = (dir.path() / "couch.yaml").string();
  std::ofstream(file) << good;
  auto ok = read_couch_calibration(file);
  ASSERT_TRUE(ok.ok()) << ok.status().message();
  ASSERT_TRUE(ok->centre_room_mm.has_value());
  EXPECT_NEAR(ok->centre_room_mm->x(), 1, 1e-12);
  const std::pair<std::pair<const char*, const char*>, const char*> cases[] = {
      {{"  rms_mm: 0.05", "  rms_mm: -1"}, "couch.yaml:4:11: couch_calibration.rms_mm must not be negative"},
      {{"  rms_mm: 0.05", "  rms_mmm: 0.05"}, "unknown key 'rms_mmm'"},
      {{"  moves: 8", "  moves: 1"}, "couch_calibration.moves must be in 3..100000"},
      {{"  centre_sd_mm: [0.1, 0.1, 0.1]", "  centre_sd_mm: [0.1, -0.1, 0.1]"}, "centre_sd_mm must not be negative"},
      {{"  centre_mm: [1, 2, 3]", "  centre_mm: [1e9, 2, 3]"}, "more than 5 m from the isocentre"},
      {{"  centre_determined: true", "  centre_determined: perhaps"}, "must be true or false"},
      {{"  rms_mm: 0.05", "  rms_mm: .nan"}, "must be finite"},
      {{"  rms_mm: 0.05", "  rms_mm: 1e9"}, "is no calibration"},
      {{"  rms_mm: 0.05\n", ""}, "needs 'rms_mm'"},
      {{"  centre_mm: [1, 2, 3]", "  centre_mm: [4000, 4000, 0]"}, "more than 5 m from the isocentre"},
      {{"  source: a test\n", "  source: a test\nother: 1\n"}, "unknown key 'other' in a couch calibration file"}};
  for (const auto& [edit, says] : cases) {
    std::string text = good;
    text.replace(text.find(edit.first), std::string(edit.first).size(), edit.second);
    std::ofstream(file, std::ios::trunc) << text;
    auto bad = read_couch_calibration(file);
    ASSERT_FALSE(bad.ok()) << edit.second;
    EXPECT_NE(bad.status().message().find(says), std::string::npos) << bad.status().message();
  }
}

// fuzz_calibration_files' first crash: a complex key in a phantom file threw out of the key
// check and aborted the program. Every YAML file lftrack reads goes through the same check.
TEST(CalibrationFiles, AComplexKeyIsRefusedNotThrown) {
  test::TempDir dir;
  const auto file = (dir.path() / "phantom.yaml").string();
  std::ofstream(file) << "name: seed\nmarker_diameter_mm: 2\n? - [0, 30, 0]\n: 1\n";
  auto phantom = load_calibration_phantom(file);
  ASSERT_FALSE(phantom.ok());
  EXPECT_NE(phantom.status().message().find("must be a plain name"), std::string::npos) << phantom.status().message();
  std::ofstream(file, std::ios::trunc) << "couch_calibration:\n  ? {a: 1}\n  : 2\n";
  auto couch = read_couch_calibration(file);
  ASSERT_FALSE(couch.ok());
  EXPECT_NE(couch.status().message().find("must be a plain name"), std::string::npos) << couch.status().message();
}

}  // namespace
}  // namespace lftrack::session
