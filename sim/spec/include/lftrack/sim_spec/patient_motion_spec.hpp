#pragma once
// Patient motion for the simulated closed loop (scene section `motion`): what the scene asks
// for, nothing more. The offset of the anatomy from where it lay at time 0, as the pose 6-vector
// about the registration origin (t [mm], omega [rad]), at a time in seconds:
//   drift      a constant velocity (mm/s, rad/s; the scene gives deg/s),
//   breathing  a periodic motion, amplitude * sin^2(pi t / period) (a breathing-like cycle that
//              rests at exhale),
//   shifts     sudden steps at given times (the patient coughs, moves an arm).
// sim::patient_offset evaluates it.

#include <vector>

#include "lftrack/tracking/pose.hpp"

namespace lftrack::sim_spec {

struct MotionStep {
  double time_s = 0;
  tracking::Vector6d delta = tracking::Vector6d::Zero();  // mm, rad
};

struct PatientMotionSpec {
  tracking::Vector6d drift_per_s = tracking::Vector6d::Zero();          // mm/s, rad/s
  tracking::Vector6d breathing_amplitude = tracking::Vector6d::Zero();  // mm, rad
  double breathing_period_s = 4.0;
  std::vector<MotionStep> shifts;
};

}  // namespace lftrack::sim_spec
