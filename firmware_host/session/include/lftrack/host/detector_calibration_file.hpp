#pragma once
// The detector calibration file (`lftrack calibrate detector --out FILE`; a scene names it as
// detectors[i].calibration): a multi-page 32-bit float TIFF, so any image viewer shows the maps
//   page 1 offset (counts), page 2 gain (1 = nominal), page 3 temporal noise (counts),
//   page 4 defects (1 = masked),
// with JSON in page 1's ImageDescription: format and version, detector, rows, cols, frame
// counts, open-field counts, saturation, the defect rule's thresholds, defects per rule, and the
// maps' content hash (calib::detector_calibration_hash), checked on loading.
//
// Written to a temporary file beside the target and renamed; an existing file is replaced only
// with `overwrite` (and only a regular file, never through a link). Loading refuses anything
// malformed with the reason: not a TIFF, another format or version, missing keys, a size that
// disagrees with the pages or exceeds 16384 a side, a page that is not float32, non-finite
// values, a negative gain, a hash that does not match.

#include <filesystem>

#include "lftrack/calib/detector_calibration.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::host {

Status write_detector_calibration(const std::filesystem::path& path, const calib::DetectorCalibration& calibration,
                                  bool overwrite);
Result<calib::DetectorCalibration> load_detector_calibration(const std::filesystem::path& path);

}  // namespace lftrack::host
