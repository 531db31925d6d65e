// A detector's calibration from dark and flood frames (calib/detector_calibration.hpp): planted
// offsets, gains and defects are found; every refusal says why.

#include "lftrack/calib/detector_calibration.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

namespace lftrack::calib {
namespace {

using Frame = tracking::Image<std::uint16_t>;

// A 64 x 48 detector: offset 100 + 10 sin, gain 1 +- 5 %, dark noise 3 counts, flood signal 2000
// counts x gain (+ shot noise); planted: a hot pixel, a dead pixel, a noisy pixel, a weak column.
struct PlantedDetector {
  static constexpr int kRows = 48, kCols = 64;
  tracking::Image<float> offset{kRows, kCols}, gain{kRows, kCols};
  std::mt19937 rng{7};
  PlantedDetector() {
    for (int r = 0; r < kRows; ++r)
      for (int c = 0; c < kCols; ++c) {
        offset.at(r, c) = float(100 + 10 * std::sin(0.1 * r + 0.2 * c));
        gain.at(r, c) = float(1 + 0.05 * std::cos(0.3 * r - 0.1 * c));
      }
    offset.at(5, 7) = 3000;  // hot
    gain.at(10, 20) = 0.05f;  // dead
    for (int r = 0; r < kRows; ++r) gain.at(r, 40) = 0.6f;  // a weak column: each pixel passes the gain test
  }
  Frame frame(double signal, bool noisy_pixel = true) {
    Frame f(kRows, kCols);
    std::normal_distribution<double> unit(0, 1);
    for (int r = 0; r < kRows; ++r)
      for (int c = 0; c < kCols; ++c) {
        const double s = signal * gain.at(r, c);
        double v = offset.at(r, c) + s + 3 * unit(rng) + std::sqrt(s) * unit(rng);
        if (noisy_pixel && r == 30 && c == 50) v += 60 * unit(rng);
        f.at(r, c) = std::uint16_t(std::clamp(std::lround(v), 0L, 65535L));
      }
    return f;
  }
  std::vector<Frame> frames(int n, double signal) {
    std::vector<Frame> v;
    for (int i = 0; i < n; ++i) v.push_back(frame(signal));
    return v;
  }
};

TEST(DetectorCalibration, FindsThePlantedOffsetGainAndDefects) {
  PlantedDetector d;
  const auto dark = d.frames(16, 0), flood = d.frames(16, 2000);
  auto c = calibrate_detector(dark, flood, {});
  ASSERT_TRUE(c.ok()) << c.status().message();
  EXPECT_EQ(c->rows, 48);
  EXPECT_EQ(c->cols, 64);
  EXPECT_EQ(c->saturation_counts, 65535);
  // The offset within 4 standard errors of the mean (3 counts / sqrt 16).
  double worst_offset = 0, worst_gain = 0;
  for (int r = 0; r < 48; ++r)
    for (int k = 0; k < 64; ++k) {
      if (c->defective.at(r, k)) continue;
      worst_offset = std::max(worst_offset, double(std::abs(c->offset_counts.at(r, k) - d.offset.at(r, k))));
      // Shot noise of 2000 counts over 16 frames: 0.57 % per pixel; 5 SDs over 3000 pixels.
      worst_gain = std::max(worst_gain, double(std::abs(c->gain.at(r, k) - d.gain.at(r, k))));
    }
  EXPECT_LT(worst_offset, 4 * 3 / 4.0 + 0.5);
  EXPECT_LT(worst_gain, 0.03);
  EXPECT_NEAR(c->open_field_counts, 2000, 40);
  EXPECT_EQ(c->defective.at(5, 7), 1) << "hot";
  EXPECT_EQ(c->defective.at(10, 20), 1) << "dead";
  EXPECT_EQ(c->defective.at(30, 50), 1) << "noisy";
  for (int r = 0; r < 48; ++r) EXPECT_EQ(c->defective.at(r, 40), 1) << "weak column, row " << r;
  EXPECT_GE(c->defects_by_rule[kDefectDark], 1);
  EXPECT_GE(c->defects_by_rule[kDefectGain], 1);
  EXPECT_GE(c->defects_by_rule[kDefectNoise], 1);
  EXPECT_EQ(c->defects_by_rule[kDefectLine], 48);
  EXPECT_LE(c->defects, 48 + 3 + 5) << "few false alarms";
  // The loop's correction masks them (gain 0) and corrects the rest.
  const tracking::DetectorCorrection corr = to_detector_correction(*c);
  EXPECT_EQ(corr.gain.at(5, 7), 0.f);
  EXPECT_GT(corr.gain.at(0, 0), 0.9f);
  EXPECT_NEAR(corr.open_field_counts, c->open_field_counts, 1e-9);
  EXPECT_EQ(c->content_hash, detector_calibration_hash(*c));
  EXPECT_EQ(c->content_hash.size(), 16u);
}

TEST(DetectorCalibration, RefusesWithAReason) {
  PlantedDetector d;
  const auto dark = d.frames(8, 0), flood = d.frames(8, 2000);
  const auto refused = [](const Result<DetectorCalibration>& r, const std::string& why) {
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find(why), std::string::npos) << r.status().message();
  };
  refused(calibrate_detector({}, flood, {}), "no dark frames");
  refused(calibrate_detector(d.frames(3, 0), flood, {}), "too few dark frames: 3 (at least 8)");
  refused(calibrate_detector(dark, d.frames(2, 2000), {}), "too few flood frames");
  auto mixed = flood;
  mixed[3] = Frame(48, 63);
  refused(calibrate_detector(dark, mixed, {}), "flood frame 4 is 63 x 48 pixels");
  refused(calibrate_detector(flood, dark, {}), "no brighter than the dark");
  refused(calibrate_detector(dark, d.frames(8, 70000), {}), "the flood saturates");
  DetectorCalibrationOptions twelve_bit;
  twelve_bit.bits = 12;  // 4095: 2100 counts of flood are fine, 5000 are not
  EXPECT_TRUE(calibrate_detector(dark, flood, twelve_bit).ok());
  refused(calibrate_detector(dark, d.frames(8, 5000), twelve_bit), "reach 4095 counts");
  DetectorCalibrationOptions bad;
  bad.dark_sd = std::nan("");
  refused(calibrate_detector(dark, flood, bad), "robust SDs");
  bad = {};
  bad.gain_low = -1;
  refused(calibrate_detector(dark, flood, bad), "gain limits");
  bad = {};
  bad.bits = 40;
  refused(calibrate_detector(dark, flood, bad), "bits must be 8 to 16");
}

}  // namespace
}  // namespace lftrack::calib
