#pragma once
// A simulated external breathing surrogate (issue 58): a chest marker's displacement along its
// main axis, as an optical tracker streams it, from the patient's breathing (patient_motion.hpp,
// whose phase curve is b(t) = sin^2(pi t / period): 0 at exhale, 1 at full inhale):
//   s(t) = amplitude * b(t + lead_s) + drift_per_s * t + noise
// - lead_s: how far the chest runs ahead of the target (positive: the chest moves first). The
//   relation between s and the target then loops, inhale and exhale on different paths
//   (hysteresis; Seppenwoolde et al., IJROBP 53 (2002) 822 report up to 0.3 s).
// - drift_per_s: the relation's slow change (the patient relaxes, the marker's skin slides); a
//   few tenths of a millimetre per minute in Hoogeman et al., IJROBP 74 (2009) 297.
// - noise_sd: the tracker's white noise, drawn from the seed (the same stream for the same seed).
// Times in seconds from the start of the run.

#include <cstdint>
#include <random>
#include "lftrack/sim_spec/breathing_surrogate_spec.hpp"

namespace lftrack::sim {

class BreathingSurrogate {
 public:
  explicit BreathingSurrogate(const sim_spec::BreathingSurrogateSpec& spec);
  // The marker's reading at t_s, with a fresh draw of the noise.
  double sample(double t_s);
  // The same without noise, and its exact rate (per second): what the model should recover.
  double exact(double t_s) const;
  double exact_rate_per_s(double t_s) const;
  const sim_spec::BreathingSurrogateSpec& spec() const { return spec_; }

 private:
  sim_spec::BreathingSurrogateSpec spec_;
  std::mt19937_64 random_;
  std::normal_distribution<double> noise_;
};

}  // namespace lftrack::sim
