#pragma once
// A flat-panel detector's correction from its own frames (`lftrack calibrate detector`): dark
// frames (no beam) give the offset and the temporal noise per pixel; flood frames (open beam,
// nothing in it) give the gain. Defective pixels are found by a stated rule and masked.
// Offline: O(pixels x frames), two passes over the dark frames, one over the flood frames.
//
//   offset(p)  = mean of the dark frames at p                                  (counts)
//   noise(p)   = standard deviation of the dark frames at p (n - 1)            (counts)
//   signal(p)  = mean of the flood frames at p - offset(p)                     (counts)
//   open field = median of signal over the pixels not defective (I0 of the line integral)
//   gain(p)    = max(0, signal(p) / open field)                                (1 = nominal)
//
// The defect rule (robust SD = 1.4826 x the median absolute deviation over all pixels; the
// robust SD used is at least 1 count for the offset and 0.5 counts for the noise, so a perfectly
// flat map does not flag a pixel one count off). A pixel is defective when it breaks any of:
//   dark       |offset - median offset|  > dark_sd  x robust SD of offset
//   noise      noise - median noise      > noise_sd x robust SD of noise
//   gain       signal / median signal (all pixels) outside [gain_low, gain_high]
//   saturated  the pixel is at or above the saturation level in any flood frame
//   line       a row or column whose median of signal / median signal is outside
//              [line_low, line_high], or of which more than line_defect_fraction of the pixels
//              break the rules above: the whole line is masked
// The saturation level (raw values at or above it are saturated, as preprocess_frame reads it):
// `saturation_counts` when given (> 0); else 2^bits - 1 when `bits` is given (> 0); else the
// smallest 2^b - 1 (b = 8..16) at or above the largest raw value in any frame ("observed": a
// 12-bit detector's frames never exceed 4095). DetectorCalibration::saturation_source says which.
//
// Refused, with the reason: options non-finite or out of range; fewer dark or flood frames than
// the minimums (default 8 each; at least 2 dark frames for a noise estimate); an empty frame or
// frames of different sizes (the frame's index is named); frames smaller than kMinDetectorSide
// on a side; two dark or two flood frames identical pixel for pixel, or dark frames without
// temporal noise at most pixels (a frozen detector, or one file copied: named); a flood of which more than
// max_saturated_fraction of the pixel values (all flood frames) reach saturation; a flood no
// brighter than the dark (median signal not above min_signal_counts, or more than
// max_unlit_fraction of the pixels with mean flood at or below mean dark); more than half the
// pixels defective.

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::calib {

// The smallest frame side calibrated: the defect rule judges each pixel against the median and
// robust SD of all pixels, and each row and column against the median, so a frame needs enough
// pixels and lines for a defect to be an outlier among them (a 1 x 1 frame is its own median:
// nothing could ever be found defective, and its gain is 1 by construction).
constexpr int kMinDetectorSide = 8;

struct DetectorCalibrationOptions {
  int min_dark_frames = 8;           // 2 .. 100000
  int min_flood_frames = 8;          // 1 .. 100000
  int saturation_counts = 0;         // 0: from bits; 1 .. 65535
  int bits = 0;                      // the detector's bit depth, 8 .. 16; 0: inferred (see above)
  double dark_sd = 6;                // robust SDs, 1 .. 1000
  double noise_sd = 6;               // robust SDs, 1 .. 1000
  double gain_low = 0.5, gain_high = 1.5;  // low in [0, 1), high in (1, 100]
  double line_low = 0.8, line_high = 1.25;  // as the gain limits
  double line_defect_fraction = 0.5;        // (0, 1]
  double max_saturated_fraction = 0.01;     // [0, 1]
  double min_signal_counts = 50;            // [0, 65535]
  double max_unlit_fraction = 0.05;         // [0, 1]
  // Where the saturation level came from, as a refusal names it; empty: the command line's option
  // (--saturation, --bits) or "the largest raw value".
  std::string saturation_named;
  // The frames' names (their files), one per frame, for the refusals that name frames; empty:
  // frames are named by their place, from 1.
  std::vector<std::string> dark_names, flood_names;
};

enum DefectRule : int { kDefectDark, kDefectNoise, kDefectGain, kDefectSaturated, kDefectLine, kDefectRules };
const char* defect_rule_name(int rule);  // "dark", "noise", "gain", "saturated", "line"

// The rule above in one paragraph with the thresholds of `options` filled in (the CLI prints it,
// the file stores it).
std::string describe_defect_rule(const DetectorCalibrationOptions& options);

struct DetectorCalibration {
  std::string detector;  // the scene's detector name it was made for (may be empty)
  int rows = 0, cols = 0;
  int dark_frames = 0, flood_frames = 0;
  tracking::Image<float> offset_counts, noise_counts, gain;  // gain >= 0 everywhere
  tracking::Image<unsigned char> defective;                  // 1: masked
  double open_field_counts = 0;
  int saturation_counts = 0;
  std::string saturation_source;  // "option", "bits" or "observed" (see above)
  double offset_median_counts = 0, noise_median_counts = 0;  // over all pixels
  std::array<std::int64_t, kDefectRules> defects_by_rule{};  // a pixel counts under each rule it breaks
  std::int64_t defects = 0;                                  // pixels masked
  DetectorCalibrationOptions rule;                           // the thresholds used
  std::string content_hash;  // detector_calibration_hash when made or loaded (the file stores the hash of what it holds)
  std::string created;       // UTC, ISO 8601; set when the file is written (empty before)
};

// Checks the options (finite, ordered, in range); the calibration is refused with the reason.
Status check_detector_calibration_options(const DetectorCalibrationOptions& options);

// The first two of `frames` (0-based indices, in order) identical pixel for pixel, if any. A real
// detector's frames always differ by their noise: identical ones are a frozen detector's, or one
// file copied. O(pixels x frames).
std::optional<std::pair<std::size_t, std::size_t>> identical_frames(
    const std::vector<tracking::Image<std::uint16_t>>& frames);

Result<DetectorCalibration> calibrate_detector(const std::vector<tracking::Image<std::uint16_t>>& dark,
                                               const std::vector<tracking::Image<std::uint16_t>>& flood,
                                               const DetectorCalibrationOptions& options);

// FNV-1a 64, as 16 hex digits, of what the loop takes from a calibration: rows, cols, the offset,
// noise, gain and defect maps, the open field, the saturation level and the detector's name (so a
// file renamed to another detector is caught). What the file stores and checks on loading.
std::string detector_calibration_hash(const DetectorCalibration& calibration);

// The loop's correction: offset, gain with defective pixels at 0 (preprocessing masks them),
// I0 and the saturation level.
tracking::DetectorCorrection to_detector_correction(const DetectorCalibration& calibration);

}  // namespace lftrack::calib
