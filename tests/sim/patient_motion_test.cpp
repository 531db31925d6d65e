#include "lftrack/sim/patient_motion.hpp"

#include <gtest/gtest.h>

namespace lftrack::sim {

using sim_spec::PatientMotionSpec;
namespace {

using tracking::Vector6d;

TEST(PatientMotion, NothingAskedNothingMoves) {
  EXPECT_EQ(patient_offset({}, 12.3), Vector6d::Zero());
}

TEST(PatientMotion, DriftBreathingAndShiftsAddUp) {
  PatientMotionSpec s;
  s.drift_per_s(0) = 0.1;
  s.breathing_amplitude(2) = 5.0;
  s.breathing_period_s = 4.0;
  Vector6d shift = Vector6d::Zero();
  shift(1) = 8.0;
  s.shifts = {{10.0, shift}};
  EXPECT_NEAR(patient_offset(s, 0)(2), 0.0, 1e-12);    // rests at exhale
  EXPECT_NEAR(patient_offset(s, 2)(2), 5.0, 1e-12);    // full inhale mid-period
  EXPECT_NEAR(patient_offset(s, 4)(2), 0.0, 1e-12);
  EXPECT_NEAR(patient_offset(s, 5)(0), 0.5, 1e-12);
  EXPECT_EQ(patient_offset(s, 9.99)(1), 0.0);
  EXPECT_EQ(patient_offset(s, 10.0)(1), 8.0);
  EXPECT_EQ(patient_offset(s, -3), patient_offset(s, 0));
}

}  // namespace
}  // namespace lftrack::sim
