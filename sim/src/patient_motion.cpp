#include "lftrack/sim/patient_motion.hpp"

#include <cmath>

namespace lftrack::sim {

using sim_spec::MotionStep;
using sim_spec::PatientMotionSpec;

tracking::Vector6d patient_offset(const PatientMotionSpec& spec, double t_s) {
  const double t = t_s > 0 ? t_s : 0.0;
  tracking::Vector6d offset = spec.drift_per_s * t;
  if (spec.breathing_period_s > 0) {
    const double s = std::sin(3.14159265358979323846 * t / spec.breathing_period_s);
    offset += spec.breathing_amplitude * (s * s);
  }
  for (const MotionStep& step : spec.shifts)
    if (t >= step.time_s) offset += step.delta;
  return offset;
}

}  // namespace lftrack::sim
