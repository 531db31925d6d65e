#pragma once
// Patient motion for the simulated closed loop: the scene's `motion` (sim_spec::PatientMotionSpec,
// whose header states the model) evaluated at a time.

#include "lftrack/sim_spec/patient_motion_spec.hpp"
#include "lftrack/tracking/pose.hpp"

namespace lftrack::sim {

// The offset at time t (s); t < 0 is treated as 0.
tracking::Vector6d patient_offset(const sim_spec::PatientMotionSpec& spec, double t_s);

}  // namespace lftrack::sim
