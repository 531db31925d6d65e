#include "lftrack/sim/panel_frames.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>

#include "lftrack/sim/poisson_sampler.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"

namespace lftrack::sim {

using sim_spec::check_detector_effects;
namespace {

bool in(double v, double lo, double hi) {
  return std::isfinite(v) && v >= lo && v <= hi;
}

}  // namespace

Status check_panel_spec(const PanelSpec& s) {
  if (s.rows < 1 || s.cols < 1 || s.rows > 16384 || s.cols > 16384)
    return invalid_argument("simulated panel: 1 to 16384 rows and columns");
  if (s.bits < 8 || s.bits > 16) return invalid_argument("simulated panel: 8 to 16 bits");
  if (!in(s.photons_per_pixel, 1e-9, sim_spec::kMaxPhotonsPerPixel) || !in(s.open_field_fraction, 1e-9, 1) ||
      !in(s.dark_fraction, 0, 0.5) || !in(s.read_noise_counts, 1e-9, 1000))
    return invalid_argument(
        "simulated panel: photons in (0, 1e9], open field in (0, 1] of full scale, dark level in [0, 0.5], "
        "read "
        "noise in (0, 1000] counts");
  if (s.effects) return check_detector_effects(*s.effects);
  return {};
}

Result<std::vector<tracking::Image<std::uint16_t>>> simulate_panel_frames(const PanelSpec& s, bool flood,
                                                                          int count, std::uint64_t seed) {
  LFTRACK_RETURN_IF_ERROR(check_panel_spec(s));
  if (count < 1 || count > 1000) return invalid_argument("simulated panel: 1 to 1000 frames");
  const double full_scale = std::ldexp(1.0, s.bits) - 1;
  const double dark = s.dark_fraction * full_scale;
  const double open_field = s.open_field_fraction * full_scale;
  const double counts_per_photon = open_field / s.photons_per_pixel;
  std::unique_ptr<DetectorPattern> pattern;
  if (s.effects) pattern = std::make_unique<DetectorPattern>(*s.effects, s.rows, s.cols);
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + (flood ? 1 : 2));
  std::normal_distribution<double> read(0, s.read_noise_counts);
  std::vector<tracking::Image<std::uint16_t>> frames;
  frames.reserve(std::size_t(count));
  for (int f = 0; f < count; ++f) {
    tracking::Image<std::uint16_t> frame(s.rows, s.cols);
    for (int r = 0; r < s.rows; ++r) {
      const double heel = pattern ? pattern->heel(r) : 1.0;
      for (int c = 0; c < s.cols; ++c) {
        const double stuck = pattern ? pattern->stuck_level(r, c) : -1.0;
        double v;
        if (stuck > 0) {
          v = stuck * open_field;
        } else {
          v = dark + read(rng);
          if (flood) {
            const double gain = pattern ? pattern->gain(r, c) : 1.0;
            v += double(poisson_draw(
                     std::min(sim_spec::kMaxPhotonsPerPixel, s.photons_per_pixel * heel * gain), rng)) *
                 counts_per_photon;
          }
        }
        frame.at(r, c) = std::uint16_t(std::clamp(std::round(v), 0.0, full_scale));
      }
    }
    frames.push_back(std::move(frame));
  }
  return frames;
}

}  // namespace lftrack::sim
