#include "lftrack/sim/detector_effects.hpp"

#include <algorithm>
#include <cmath>

namespace lftrack::sim {

using sim_spec::DetectorEffectsSpec;

namespace {

std::uint64_t splitmix(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}
// A uniform number in [0, 1) for (seed, a, b, salt): the same pixel, the same number.
double uniform(std::uint64_t seed, std::uint64_t a, std::uint64_t b, std::uint64_t salt) {
  const std::uint64_t h = splitmix(splitmix(splitmix(seed ^ (salt << 56)) ^ a) ^ (b * 0x632be59bd9b4e019ULL));
  return double(h >> 11) * 0x1.0p-53;
}
double normal(std::uint64_t seed, std::uint64_t a, std::uint64_t b, std::uint64_t salt) {
  const double u1 = std::max(1e-300, uniform(seed, a, b, salt));
  const double u2 = uniform(seed, a, b, salt + 1);
  return std::sqrt(-2 * std::log(u1)) * std::cos(2 * M_PI * u2);
}

}  // namespace

DetectorPattern::DetectorPattern(const DetectorEffectsSpec& spec, int rows, int cols)
    : spec_(spec), rows_(std::max(1, rows)), cols_(std::max(1, cols)) {
  // Three plane waves with periods of a quarter to a whole detector: rms of their sum is
  // amplitude * sqrt(3 / 2).
  wave_amplitude_ = spec.gain_smooth_rms / std::sqrt(1.5);
  for (int k = 0; k < 3; ++k) {
    const double period_px = std::max(rows_, cols_) * (0.25 + 0.75 * uniform(spec.pattern_seed, k, 0, 1));
    const double angle = 2 * M_PI * uniform(spec.pattern_seed, k, 1, 1);
    wave_kx_[k] = 2 * M_PI / period_px * std::cos(angle);
    wave_ky_[k] = 2 * M_PI / period_px * std::sin(angle);
    wave_phase_[k] = 2 * M_PI * uniform(spec.pattern_seed, k, 2, 1);
  }
  lines_ = std::clamp(spec.defective_lines, 0, 8);
  for (int l = 0; l < lines_; ++l) {
    const bool row = uniform(spec.pattern_seed, l, 0, 3) < 0.5;
    const int n = row ? rows_ : cols_;
    const int at = std::min(n - 1, int(uniform(spec.pattern_seed, l, 1, 3) * n));
    line_index_[l] = row ? at : rows_ + at;
    const double size = 0.05 + 0.15 * uniform(spec.pattern_seed, l, 2, 3);
    line_gain_[l] = uniform(spec.pattern_seed, l, 3, 3) < 0.5 ? 1 - size : 1 + size;
  }
}

double DetectorPattern::heel(int row) const { return 1 + spec_.heel_gradient * ((row + 0.5) / rows_ - 0.5); }

double DetectorPattern::gain(int row, int col) const {
  double g = 1;
  if (wave_amplitude_ > 0)
    for (int k = 0; k < 3; ++k) g += wave_amplitude_ * std::cos(wave_kx_[k] * col + wave_ky_[k] * row + wave_phase_[k]);
  if (spec_.gain_pixel_rms > 0) g *= 1 + spec_.gain_pixel_rms * normal(spec_.pattern_seed, std::uint64_t(row), std::uint64_t(col), 5);
  for (int l = 0; l < lines_; ++l)
    if (line_index_[l] == row || line_index_[l] == rows_ + col) g *= line_gain_[l];
  return std::max(0.0, g);
}

double DetectorPattern::stuck_level(int row, int col) const {
  if (spec_.defective_pixel_fraction <= 0) return -1;
  if (uniform(spec_.pattern_seed, std::uint64_t(row), std::uint64_t(col), 7) >= spec_.defective_pixel_fraction) return -1;
  return 0.05 + 1.15 * uniform(spec_.pattern_seed, std::uint64_t(row), std::uint64_t(col), 8);
}

}  // namespace lftrack::sim
