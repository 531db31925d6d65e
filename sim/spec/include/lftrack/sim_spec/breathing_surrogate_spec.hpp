#pragma once
// A simulated chest marker (scene section `surrogate.sim`; issue 58), as data: its travel, lead,
// drift and noise, and the tracker's stream. sim::BreathingSurrogate (breathing_surrogate.hpp)
// draws the readings and states the model.

#include <cstdint>

namespace lftrack::sim_spec {

struct BreathingSurrogateSpec {
  double amplitude = 10;       // the marker's travel from exhale to inhale (mm)
  double period_s = 4.0;       // the patient's breathing period (the scene's motion)
  double lead_s = 0.2;         // the chest ahead of the target
  double drift_per_s = 0.0;    // mm/s
  double noise_sd = 0.1;       // mm
  double sample_rate_hz = 60;  // the tracker's stream
  std::uint64_t seed = 1;
};

}  // namespace lftrack::sim_spec
