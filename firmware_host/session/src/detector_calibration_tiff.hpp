#pragma once
// The pages of a detector calibration file (detector_calibration_file.hpp): four one-sample
// 32-bit float TIFF pages in strips, written and read with libtiff. Private to the session library.

#include <tiffio.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/calib/detector_calibration.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::session::calibration_tiff {

inline constexpr int kPages = 4;
inline constexpr const char* kPageNames[kPages] = {"offset_counts", "gain", "noise_counts", "defects"};

// Writes the pages to `file` (the first carries `description`) and flushes them to disk.
Status write_tiff(const std::filesystem::path& file, const calib::DetectorCalibration& c,
                  const std::string& description);
// Page `page` (0-based) of `rows` x `cols` into `out`; a wrong size, type or a non-finite value
// is corrupt data named with `where`.
Status read_page(TIFF* tif, int page, int rows, int cols, std::vector<float>* out, const std::string& where);
// Where the last page's directory ends, out-of-line values included, read from the file
// itself: a file cut there still gives libtiff its four pages (it forgives a short page name),
// but it is not what was written. 0 when the directory cannot be read.
std::uint64_t last_directory_end(TIFF* tif, const std::filesystem::path& path);

}  // namespace lftrack::session::calibration_tiff
