#pragma once
// Folders of detector frames, as `lftrack calibrate detector` and `lftrack qa detector` read them:
// each holds only frames, 16-bit greyscale .tif/.tiff/.png files of one size, used in file name
// order (names starting with '.' are skipped). Anything else in it (a notes file, a folder, an
// 8-bit image) is refused with its name, so a mixed-up folder is not read from. At most 5000
// frames, and 4 GiB of them held at once.

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::cli {

// The frame files of `dir` in name order; a folder that is missing, empty of frames or holds
// anything else is refused. `what` names the folder in errors ("dark", "flood").
Result<std::vector<std::filesystem::path>> list_frame_folder(const std::string& dir, const char* what);

struct FrameSize {
  int rows = 0, cols = 0;
  std::filesystem::path first;  // the file the size was taken from
  std::uint64_t bytes = 0;      // of the frames read so far
};

// Reads `files`, all of the size in `size` (set from the first file when not yet set).
Result<std::vector<tracking::Image<std::uint16_t>>> read_frame_files(
    const std::vector<std::filesystem::path>& files, const char* what, FrameSize* size);

}  // namespace lftrack::cli
