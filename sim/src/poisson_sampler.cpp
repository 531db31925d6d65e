#include "lftrack/sim/poisson_sampler.hpp"

#include <cmath>

namespace lftrack::sim {
namespace {

// A uniform double in [0, 1) from the generator's top 53 bits.
double uniform(std::mt19937_64& rng) { return double(rng() >> 11) * 0x1.0p-53; }

// Multiplying uniforms until their product falls below e^-mean (Knuth): about mean + 1 uniforms.
std::int64_t small_mean(double mean, std::mt19937_64& rng) {
  const double limit = std::exp(-mean);
  std::int64_t k = 0;
  double product = uniform(rng);
  while (product > limit) {
    ++k;
    product *= uniform(rng);
  }
  return k;
}

// PTRS (Hoermann 1993), for mean >= 10: a candidate from a transformed uniform, accepted at once
// inside the squeeze (most draws) or by the exact density test.
std::int64_t large_mean(double mean, std::mt19937_64& rng) {
  const double root = std::sqrt(mean);
  const double b = 0.931 + 2.53 * root;
  const double a = -0.059 + 0.02483 * b;
  const double inv_alpha = 1.1239 + 1.1328 / (b - 3.4);
  const double v_r = 0.9277 - 3.6224 / (b - 2);
  const double log_mean = std::log(mean);
  for (;;) {
    const double u = uniform(rng) - 0.5;
    const double v = uniform(rng);
    const double us = 0.5 - std::abs(u);
    const double k = std::floor((2 * a / us + b) * u + mean + 0.43);
    if (us >= 0.07 && v <= v_r) return static_cast<std::int64_t>(k);
    if (k < 0 || (us < 0.013 && v > us)) continue;
    if (std::log(v) + std::log(inv_alpha) - std::log(a / (us * us) + b) <= -mean + k * log_mean - std::lgamma(k + 1))
      return static_cast<std::int64_t>(k);
  }
}

}  // namespace

std::int64_t poisson_draw(double mean, std::mt19937_64& rng) {
  if (!(mean > 0)) return 0;
  return mean < 10 ? small_mean(mean, rng) : large_mean(mean, rng);
}

}  // namespace lftrack::sim
