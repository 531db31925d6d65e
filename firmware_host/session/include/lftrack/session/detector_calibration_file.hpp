#pragma once
// The detector calibration file (`lftrack calibrate detector --out FILE`; a scene names it as
// detectors[i].calibration): a multi-page 32-bit float TIFF, uncompressed, so any image viewer
// shows the maps
//   page 1 offset (counts), page 2 gain (1 = nominal), page 3 temporal noise (counts),
//   page 4 defects (1 = masked, 0 = good),
// with JSON in page 1's ImageDescription:
//   format "lftrack detector calibration", version 2, pages (the four names), detector, rows,
//   cols, dark_frames, flood_frames, open_field_counts, saturation_counts, saturation_source,
//   offset_median_counts, noise_median_counts, defect_rule {text, dark_sd, noise_sd, gain_low,
//   gain_high, line_low, line_high, line_defect_fraction, max_saturated_fraction,
//   min_signal_counts, max_unlit_fraction, min_dark_frames, min_flood_frames, bits},
//   defects {dark, noise, gain, saturated, line, masked}, hash_algorithm "FNV-1a 64",
//   content_hash (calib::detector_calibration_hash of the maps, levels and detector name,
//   computed as the file is written), created (UTC, ISO 8601).
//
// Written to a temporary file beside the target, flushed to disk, then linked into place (so an
// existing file is never replaced, even one that appears meanwhile) or, with `overwrite`,
// renamed over it (only a regular file, never through a link or onto a folder); the temporary
// is removed on any failure. The parent folder must exist.
//
// Loading refuses anything malformed with the reason, and allocates for the maps only after the
// file's size has been checked against the metadata: not a TIFF, not four pages, metadata that
// is missing, not JSON, over 1 MiB, of another format or version, a key missing or of the wrong
// type or out of range, a size over 16384 a side or disagreeing with a page, a page that is not
// one-sample float32 in strips, non-finite values, a negative gain or noise, a defect page with
// values other than 0 and 1 or a count other than the metadata's, a hash that does not match.

#include <filesystem>

#include "lftrack/calib/detector_calibration.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::session {

inline constexpr int kDetectorCalibrationVersion = 2;

// `calibration.created` is ignored: the time of writing is stored.
Status write_detector_calibration(const std::filesystem::path& path,
                                  const calib::DetectorCalibration& calibration, bool overwrite);
Result<calib::DetectorCalibration> load_detector_calibration(const std::filesystem::path& path);

// The time a file of record is stamped with: UTC, ISO 8601 to the second ("2026-11-30T12:00:00Z").
std::string utc_now();

}  // namespace lftrack::session
