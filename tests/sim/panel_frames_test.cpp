// A simulated panel's dark and flood frames (sim/panel_frames.hpp): the levels and noise the
// header states, the detector's own fixed pattern (the stuck pixels the loop's frames carry), the
// same frames for the same seed, and absurd specs refused.

#include "lftrack/sim/panel_frames.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace lftrack::sim {

using sim_spec::DetectorEffectsSpec;
namespace {

struct Moments {
  double mean = 0, sd = 0;
};
// Mean and SD over frames of pixel (r, c).
Moments at(const std::vector<tracking::Image<std::uint16_t>>& f, int r, int c) {
  Moments m;
  for (const auto& x : f) m.mean += x.at(r, c) / double(f.size());
  for (const auto& x : f) m.sd += std::pow(x.at(r, c) - m.mean, 2) / double(f.size() - 1);
  m.sd = std::sqrt(m.sd);
  return m;
}

TEST(PanelFrames, DarkAndFloodCarryTheStatedLevelsAndNoise) {
  PanelSpec s;
  s.rows = 40;
  s.cols = 50;
  s.bits = 12;
  s.photons_per_pixel = 5000;
  s.open_field_fraction = 0.5;
  s.dark_fraction = 0.01;
  s.read_noise_counts = 2;
  auto dark = simulate_panel_frames(s, false, 64, 1);
  auto flood = simulate_panel_frames(s, true, 64, 1);
  ASSERT_TRUE(dark.ok() && flood.ok());
  ASSERT_EQ(dark->size(), 64u);
  EXPECT_EQ((*dark)[0].rows(), 40);
  EXPECT_EQ((*dark)[0].cols(), 50);
  const double dark_level = 0.01 * 4095, open = 0.5 * 4095, counts_per_photon = open / 5000;
  double mean_dark = 0, mean_flood = 0, sd_dark = 0, sd_flood = 0;
  for (int r = 0; r < 40; ++r)
    for (int c = 0; c < 50; ++c) {
      const Moments d = at(*dark, r, c), f = at(*flood, r, c);
      mean_dark += d.mean / 2000;
      mean_flood += f.mean / 2000;
      sd_dark += d.sd / 2000;
      sd_flood += f.sd / 2000;
    }
  EXPECT_NEAR(mean_dark, dark_level, 0.2);
  EXPECT_NEAR(sd_dark, 2.0, 0.15) << "the read noise (quantisation adds 1/12 count^2)";
  EXPECT_NEAR(mean_flood, dark_level + open, 1.0);
  // Poisson: sqrt(5000) photons x counts per photon, with the read noise beside it.
  EXPECT_NEAR(sd_flood, std::hypot(std::sqrt(5000.0) * counts_per_photon, 2.0), 1.0);

  auto again = simulate_panel_frames(s, true, 64, 1);
  ASSERT_TRUE(again.ok());
  for (std::size_t f = 0; f < 64; ++f) EXPECT_EQ((*again)[f].pixels(), (*flood)[f].pixels()) << "frame " << f;
  auto other = simulate_panel_frames(s, true, 64, 2);
  ASSERT_TRUE(other.ok());
  int differ = 0;
  for (int c = 0; c < 50; ++c) differ += (*other)[0].at(3, c) != (*flood)[0].at(3, c);
  EXPECT_GT(differ, 25) << "another seed, other noise";
  // The dark and flood frames of one seed draw their noise apart: their residuals about each
  // pixel's mean are uncorrelated (|r| < 0.05 over 128,000 pairs; 0.003 expected).
  double sxy = 0, sxx = 0, syy = 0;
  for (int r = 0; r < 40; ++r)
    for (int c = 0; c < 50; ++c) {
      const Moments d = at(*dark, r, c), f = at(*flood, r, c);
      for (std::size_t i = 0; i < 64; ++i) {
        const double x = (*dark)[i].at(r, c) - d.mean, y = (*flood)[i].at(r, c) - f.mean;
        sxy += x * y;
        sxx += x * x;
        syy += y * y;
      }
    }
  EXPECT_LT(std::abs(sxy / std::sqrt(sxx * syy)), 0.05);
}

TEST(PanelFrames, StuckPixelsReadTheirLevelInEveryFrameAsTheDetectorPatternSays) {
  PanelSpec s;
  s.rows = 64;
  s.cols = 64;
  DetectorEffectsSpec e;
  e.defective_pixel_fraction = 0.01;
  s.effects = e;
  const DetectorPattern pattern(e, 64, 64);
  auto dark = simulate_panel_frames(s, false, 4, 3);
  auto flood = simulate_panel_frames(s, true, 4, 3);
  ASSERT_TRUE(dark.ok() && flood.ok());
  int stuck = 0;
  const double open = s.open_field_fraction * 4095;
  for (int r = 0; r < 64; ++r)
    for (int c = 0; c < 64; ++c) {
      const double level = pattern.stuck_level(r, c);
      if (level <= 0) continue;
      ++stuck;
      const double expected = std::min(4095.0, std::round(level * open));
      for (int f = 0; f < 4; ++f) {
        EXPECT_EQ((*dark)[std::size_t(f)].at(r, c), expected) << r << ", " << c;
        EXPECT_EQ((*flood)[std::size_t(f)].at(r, c), expected) << r << ", " << c;
      }
    }
  EXPECT_GT(stuck, 10) << "1 % of 4,096 pixels";
}

TEST(PanelFrames, AbsurdSpecsAreRefused) {
  const double nan = std::nan(""), inf = std::numeric_limits<double>::infinity();
  auto refused = [](PanelSpec s, int count = 4) { return !simulate_panel_frames(s, true, count, 1).ok(); };
  PanelSpec good;
  good.rows = good.cols = 16;
  EXPECT_FALSE(refused(good));
  for (double bad : {0.0, -1.0, nan, inf, 1e12}) {
    PanelSpec s = good;
    s.photons_per_pixel = bad;
    EXPECT_TRUE(refused(s)) << "photons " << bad;
    s = good;
    s.read_noise_counts = bad;
    EXPECT_TRUE(refused(s)) << "read noise " << bad;
    s = good;
    s.open_field_fraction = bad;
    EXPECT_TRUE(refused(s)) << "open field " << bad;
  }
  PanelSpec s = good;
  s.rows = 0;
  EXPECT_TRUE(refused(s));
  s = good;
  s.bits = 17;
  EXPECT_TRUE(refused(s));
  EXPECT_TRUE(refused(good, 0));
  EXPECT_TRUE(refused(good, 1001));
}

}  // namespace
}  // namespace lftrack::sim
