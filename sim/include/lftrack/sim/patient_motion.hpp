#pragma once
// Patient motion for the simulated closed loop: what the scene asks for, nothing more. The offset
// of the anatomy from where it lay at time 0, as the pose 6-vector about the registration origin
// (t [mm], omega [rad]), at a time in seconds:
//   drift      a constant velocity (mm/s, deg/s),
//   breathing  a periodic motion, amplitude * sin^2(pi t / period) (a breathing-like cycle that
//              rests at exhale),
//   shifts     sudden steps at given times (the patient coughs, moves an arm).

#include <vector>

#include "lftrack/sim_spec/patient_motion_spec.hpp"
#include "lftrack/tracking/pose.hpp"

namespace lftrack::sim {

// The offset at time t (s); t < 0 is treated as 0.
tracking::Vector6d patient_offset(const sim_spec::PatientMotionSpec& spec, double t_s);

}  // namespace lftrack::sim
