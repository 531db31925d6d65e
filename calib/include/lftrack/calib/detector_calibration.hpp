#pragma once
// A flat-panel detector's correction from its own frames (`lftrack calibrate detector`): dark
// frames (no beam) give the offset and the temporal noise per pixel; flood frames (open beam,
// nothing in it) give the gain. Defective pixels are found by a stated rule and masked.
//
//   offset(p)  = mean of the dark frames at p                                  (counts)
//   noise(p)   = standard deviation of the dark frames at p                   (counts)
//   signal(p)  = mean of the flood frames at p - offset(p)                     (counts)
//   gain(p)    = signal(p) / median of signal over the pixels not defective    (1 = nominal)
//   open field = that median (I0 of the line integral, dark-corrected counts)
//
// The defect rule (robust SD = 1.4826 x the median absolute deviation):
//   dark       |offset - median offset|  > dark_sd  x robust SD of offset
//   noise      noise - median noise      > noise_sd x robust SD of noise
//   gain       gain < gain_low or gain > gain_high (first against the median of all signals)
//   saturated  the pixel reaches the saturation level in any flood frame
//   line       a row or column whose median gain is outside [line_low, line_high] (all its
//              pixels then count as defective)
// Refused, with the reason: fewer frames than the minimums, frames of different sizes, a flood
// of which more than max_saturated_fraction of pixels saturate, a flood no brighter than the
// dark (median signal under min_signal_counts), anything non-finite in the options.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::calib {

struct DetectorCalibrationOptions {
  int min_dark_frames = 8;
  int min_flood_frames = 8;
  int saturation_counts = 0;  // 0: 2^bits - 1
  int bits = 16;              // the detector's bit depth (8..16)
  double dark_sd = 6;
  double noise_sd = 6;
  double gain_low = 0.5, gain_high = 1.5;
  double line_low = 0.8, line_high = 1.25;
  double max_saturated_fraction = 0.01;
  double min_signal_counts = 50;
};

enum DefectRule : int { kDefectDark, kDefectNoise, kDefectGain, kDefectSaturated, kDefectLine, kDefectRules };
const char* defect_rule_name(int rule);  // "dark", "noise", "gain", "saturated", "line"

struct DetectorCalibration {
  std::string detector;  // the scene's detector name it was made for (may be empty)
  int rows = 0, cols = 0;
  int dark_frames = 0, flood_frames = 0;
  tracking::Image<float> offset_counts, noise_counts, gain;
  tracking::Image<unsigned char> defective;  // 1: masked
  double open_field_counts = 0;
  int saturation_counts = 0;
  std::array<std::int64_t, kDefectRules> defects_by_rule{};  // a pixel counts under each rule it breaks
  std::int64_t defects = 0;                                  // pixels masked
  DetectorCalibrationOptions rule;                           // the thresholds used
  std::string content_hash;  // FNV-1a 64 of the maps and levels, hex (detector_calibration_hash)
};

// Checks the options (finite, ordered, in range); the calibration is refused with the reason.
Status check_detector_calibration_options(const DetectorCalibrationOptions& options);

Result<DetectorCalibration> calibrate_detector(const std::vector<tracking::Image<std::uint16_t>>& dark,
                                               const std::vector<tracking::Image<std::uint16_t>>& flood,
                                               const DetectorCalibrationOptions& options);

// The hash of the maps and levels (what the file stores and checks on loading).
std::string detector_calibration_hash(const DetectorCalibration& calibration);

// The loop's correction: offset, gain with defective pixels at 0 (preprocessing masks them),
// I0 and the saturation level.
tracking::DetectorCorrection to_detector_correction(const DetectorCalibration& calibration);

}  // namespace lftrack::calib
