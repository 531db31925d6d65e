// The couch in the room (issue 8): a virtual couch mounted 1 degree off about each axis, with its
// rotation centre 200 mm from the isocentre, is calibrated by driving it through known moves with
// the phantom on it; the loop then commands it through the recovered calibration and tracks as
// well as with the true mounting.

#include <gtest/gtest.h>

#include <cstdio>

#include "lftrack/sim_devices/couch_calibration_run.hpp"
#include "lftrack/studies/geometry_sensitivity.hpp"
#include "loop_fixture.hpp"

namespace lftrack::session {

using sim_devices::run_simulated_couch_calibration;

using studies::run_geometry_sensitivity;
using studies::SensitivityCase;
using studies::SensitivityOptions;

using loop::LoopSummary;
namespace {

CouchMountingSpec misaligned() {
  CouchMountingSpec m;
  m.rotation_rad = Eigen::Vector3d(1, 1, 1) * tracking::deg_to_rad(1.0);
  m.centre_room_mm = Eigen::Vector3d(5, -30, 200);
  return m;
}

CouchMountingSpec mounting_of(const Eigen::Isometry3d& x) {
  CouchMountingSpec m;
  m.rotation_rad = tracking::rotation_log(x.linear());
  m.centre_room_mm = x.translation();
  return m;
}

TEST_F(ClosedLoop, AMisalignedCouchIsRecoveredAndTracksAsWithItsTrueMounting) {
  // 1. Calibrate the misaligned couch with the phantom on it.
  Scene scene = small_scene(kBreathing, kLightFieldFrames);
  scene.actuator.mounting = misaligned();
  auto prepared = prepare_scene(scene, "", pool_);
  ASSERT_TRUE(prepared.ok()) << prepared.status().message();
  auto run = run_simulated_couch_calibration(*prepared, {});
  ASSERT_TRUE(run.ok()) << run.status().message();
  EXPECT_LT(run->rotation_error_deg, 0.05);
  EXPECT_LT(run->centre_error_mm, 0.5);
  EXPECT_LT(run->calibration.rms_mm, 0.05);
  EXPECT_TRUE(run->calibration.centre_determined);

  // 2. The closed loop through the true and through the recovered calibration.
  const Eigen::Isometry3d recovered = run->calibration.T_room_from_couch;
  const auto loop_with = [&](std::optional<CouchMountingSpec> calibration) {
    edit_scene_ = [&](Scene& s) {
      s.actuator.mounting = misaligned();
      s.actuator.calibration = calibration;
    };
    return run_loop(kBreathing, 120).summary;
  };
  const LoopSummary with_truth = loop_with(misaligned());
  const LoopSummary with_recovered = loop_with(mounting_of(recovered));
  const LoopSummary assumed = loop_with(std::nullopt);
  ASSERT_TRUE(with_truth.residual_mean_mm && with_recovered.residual_mean_mm && assumed.residual_mean_mm);
  std::printf(
      "residual mean / p95 mm: true mounting %.4f / %.4f, recovered %.4f / %.4f, assumed axes %.4f / %.4f\n",
      *with_truth.residual_mean_mm, *with_truth.residual_p95_mm, *with_recovered.residual_mean_mm,
      *with_recovered.residual_p95_mm, *assumed.residual_mean_mm, *assumed.residual_p95_mm);
  expect_tracks_every_cycle(with_recovered, 120);
  // The registration's wall-clock budget lets a loaded host end some searches earlier, so two
  // runs of one configuration differ by up to 0.01 mm in mean and 0.05 mm in p95 (measured with
  // four copies of this test on two cores); the calibrations are compared beyond that spread,
  // and against the 4 mm of a couch whose axes are only assumed.
  EXPECT_NEAR(*with_recovered.residual_mean_mm, *with_truth.residual_mean_mm, 0.03);
  EXPECT_NEAR(*with_recovered.residual_p95_mm, *with_truth.residual_p95_mm, 0.1);
  EXPECT_GT(*assumed.residual_mean_mm, 1.0) << "the assumed axes hold the loop far from the target";
}

}  // namespace
}  // namespace lftrack::session

#include "lftrack/studies/geometry_sensitivity.hpp"

namespace lftrack::session {
namespace {

// The sensitivity study on the small scene, one registration per case: the error-free case adds
// nothing; a source moved 1 mm across its beam shifts the anatomy's projection in that view and
// costs a tenth of a millimetre or more; every figure is finite.
TEST_F(ClosedLoop, SensitivityStudyMeasuresWhatEachCalibrationErrorCosts) {
  auto prepared = prepare_scene(small_scene(kBreathing, kLightFieldFrames), "", pool_);
  ASSERT_TRUE(prepared.ok()) << prepared.status().message();
  SensitivityOptions options;
  options.runs = 1;
  auto report = run_geometry_sensitivity(*prepared, options, pool_);
  ASSERT_TRUE(report.ok()) << report.status().message();
  ASSERT_GE(report->cases.size(), 5u);
  EXPECT_EQ(report->cases[0].name, "no error");
  EXPECT_EQ(report->cases[0].mean_added_mm, 0);
  EXPECT_LT(report->cases[0].mean_tre_mm, 0.5);
  for (const SensitivityCase& c : report->cases) {
    EXPECT_TRUE(std::isfinite(c.mean_tre_mm) && std::isfinite(c.mean_added_mm)) << c.name;
    std::printf("%-76s TRE %.3f mm, added %.3f mm\n", c.name.c_str(), c.mean_tre_mm, c.mean_added_mm);
  }
  const auto across = std::find_if(report->cases.begin(), report->cases.end(), [](const SensitivityCase& c) {
    return c.name.find("across its beam") != std::string::npos;
  });
  ASSERT_NE(across, report->cases.end());
  EXPECT_GT(across->mean_added_mm, 0.1);
  EXPECT_EQ(to_json(*report)["cases"].size(), report->cases.size());
}

}  // namespace
}  // namespace lftrack::session
