#include "lftrack/sim/breathing_surrogate.hpp"

#include <cmath>
#include <numbers>

namespace lftrack::sim {

using sim_spec::BreathingSurrogateSpec;

BreathingSurrogate::BreathingSurrogate(const BreathingSurrogateSpec& spec)
    : spec_(spec), random_(spec.seed), noise_(0.0, 1.0) {}

double BreathingSurrogate::exact(double t_s) const {
  const double phase = std::sin(std::numbers::pi * (t_s + spec_.lead_s) / spec_.period_s);
  return spec_.amplitude * phase * phase + spec_.drift_per_s * t_s;
}

double BreathingSurrogate::exact_rate_per_s(double t_s) const {
  // d/dt sin^2(w t') = w sin(2 w t'), w = pi / period
  const double w = std::numbers::pi / spec_.period_s;
  return spec_.amplitude * w * std::sin(2 * w * (t_s + spec_.lead_s)) + spec_.drift_per_s;
}

double BreathingSurrogate::sample(double t_s) {
  return exact(t_s) + spec_.noise_sd * noise_(random_);
}

}  // namespace lftrack::sim
