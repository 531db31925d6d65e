#pragma once
// A detector's daily image-quality check against its calibration (issue 59; the constancy tests
// of AAPM TG-150 and IEC 61223 for flat panels, reduced to what the loop depends on). Today's
// dark and flood frames are calibrated by the calibration's own defect rule
// (detector_calibration.hpp), and what the loop would get wrong is measured against the
// calibration it corrects a device's frames with (the `baseline`):
//
//   dark drift    median over pixels good in both of (today's offset - baseline offset), counts.
//                 The loop subtracts the baseline's offset: a drift d at a pixel that reads a
//                 fraction f of the open field I0 changes its transmission by d / (f x I0),
//                 relative, and its line integral by about as much (nats). Judged against
//                 max_dark_drift_fraction of the baseline's open field (0.2 %: 0.002 / f in the
//                 line integral; 0.02 where the anatomy lets 10 % through).
//   noise         the root of today's mean temporal variance over the good pixels over the
//                 baseline's (a variance is unbiased whatever the frame count): electronics that
//                 degrade (above max_noise_ratio, 1.5) or a read-out that no longer follows the
//                 signal (below 1 / max_noise_ratio).
//   uniformity    today's flood as the loop corrects it, (flood mean - baseline offset) /
//                 baseline gain, averaged over blocks of a grid (8 x 8, each at least 8 pixels a
//                 side, over pixels good in both maps); (largest - smallest block) / mean of the
//                 blocks. A flat field that no longer holds (the gain drifted since the
//                 calibration, or a flood taken otherwise than the calibration's) shows as
//                 structure that no pose explains. Judged against max_nonuniformity (2 %; a
//                 freshly calibrated panel reads well under 1 %).
//   new defects   pixels defective today and not masked by the baseline: the loop reads them as
//                 anatomy. Judged against max_new_defect_fraction of the pixels (0.01 %: 26 on a
//                 512 x 512 panel) and no new defective line (a row or column of which more than
//                 the rule's line_defect_fraction is newly defective). A pixel near the rule's
//                 threshold can be found one day and not the next (then counted as healed): the
//                 limit leaves room for a few.
//   open field    today's / the baseline's: the tube's output more than the detector's; reported,
//                 not judged (the loop's similarity measures do not depend on the line
//                 integrals' constant offset).
//
// Refused, with the reason (the QA reports it as the check's failure): a baseline without its
// maps, frames of another size than the calibration's, whatever calibrate_detector refuses in
// today's frames (too few, a frozen detector, a flood no brighter than the dark), no pixel good
// in both. O(pixels x frames).

#include <cstdint>
#include <string>
#include <vector>

#include "lftrack/calib/detector_calibration.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::calib {

// Today's frames of each kind: at least 8 (fewer flag pixels by their noise alone: from 2 frames
// 63 of a 512 x 512 panel's, from 4 frames 3, from 5 none; an outside probe's count), at most
// 1,000 (what a simulated panel gives).
inline constexpr int kMinQaFrames = 8;
inline constexpr int kMaxQaFrames = 1000;

struct DetectorQaTolerances {
  double max_dark_drift_fraction = 0.002;  // of the baseline's open field, (0, 1]
  double max_noise_ratio = 1.5;            // today's median temporal noise / the baseline's, > 1
  double max_nonuniformity = 0.02;         // (0, 1]
  double max_new_defect_fraction = 1e-4;   // of the pixels, [0, 1]
  int min_frames = kMinQaFrames;           // dark and flood each, kMinQaFrames .. kMaxQaFrames
};

Status check_detector_qa_tolerances(const DetectorQaTolerances& tolerances);

struct DetectorQaResult {
  double dark_drift_counts = 0, dark_drift_limit_counts = 0;
  double noise_ratio = 0;
  double nonuniformity = 0;  // fraction
  int blocks = 0;            // blocks the uniformity was measured over
  double open_field_ratio = 0;
  std::int64_t pixels = 0;
  std::int64_t new_defects = 0;     // defective today, not masked in the baseline
  std::int64_t healed_defects = 0;  // masked in the baseline, not defective today (reported)
  std::int64_t new_defect_limit = 0;
  std::vector<std::string> new_lines;  // "row 40", "column 12"
  bool passed = false;
  std::string measured;  // every figure, in one line with units
  std::string why;       // the first tolerance missed; empty when passed
};

// Today's `dark` and `flood` frames against `baseline` (a loaded or just-made calibration).
Result<DetectorQaResult> check_detector_quality(const DetectorCalibration& baseline,
                                                const std::vector<tracking::Image<std::uint16_t>>& dark,
                                                const std::vector<tracking::Image<std::uint16_t>>& flood,
                                                const DetectorQaTolerances& tolerances);

}  // namespace lftrack::calib
