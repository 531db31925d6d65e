// Folders of detector frames (frame_folders.hpp).

#include "frame_folders.hpp"

#include <algorithm>
#include <cctype>

#include "lftrack/drivers/frame_files.hpp"

namespace lftrack::cli {

namespace fs = std::filesystem;

namespace {

constexpr std::size_t kMaxFrames = 5000;
constexpr std::uint64_t kMaxBytes = std::uint64_t(4) << 30;  // frames held in memory at once

bool is_frame_file(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext == ".tif" || ext == ".tiff" || ext == ".png";
}

}  // namespace

// The frame files of `dir` in name order; a folder that is missing, empty of frames or holds
// anything else is refused.
Result<std::vector<fs::path>> list_frame_folder(const std::string& dir, const char* what) {
  std::error_code ec;
  const fs::file_status st = fs::status(dir, ec);
  if (!fs::exists(st)) return not_found(std::string(what) + " folder " + dir + ": no such directory");
  if (!fs::is_directory(st))
    return invalid_argument(std::string(what) + " folder " + dir + " is not a directory");
  std::vector<fs::path> files;
  std::vector<std::string> others;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const fs::path& p = it->path();
    if (p.filename().string().front() == '.') continue;
    if (it->is_regular_file(ec) && is_frame_file(p))
      files.push_back(p);
    else
      others.push_back(p.filename().string() + (it->is_directory(ec) ? "/" : ""));
  }
  if (ec) return io_error(std::string(what) + " folder " + dir + ": " + ec.message());
  if (!others.empty()) {
    std::sort(others.begin(), others.end());
    std::string names;
    for (std::size_t i = 0; i < others.size() && i < 3; ++i) names += (i ? ", " : "") + others[i];
    if (others.size() > 3) names += " and " + std::to_string(others.size() - 3) + " more";
    return invalid_argument(std::string(what) + " folder " + dir + " holds " + std::to_string(others.size()) +
                            (others.size() == 1 ? " entry that is" : " entries that are") +
                            " not a frame file (.tif, .tiff, .png): " + names +
                            "; a frame folder must hold only its frames");
  }
  if (files.empty())
    return invalid_argument(std::string(what) + " folder " + dir +
                            " holds no frames (.tif, .tiff or .png files)");
  if (files.size() > kMaxFrames)
    return invalid_argument(std::string(what) + " folder " + dir + " holds " + std::to_string(files.size()) +
                            " frames; at most " + std::to_string(kMaxFrames) + " are read");
  std::sort(files.begin(), files.end());
  return files;
}

// Reads `files`, all of the size in `size` (set from the first file when not yet set).
Result<std::vector<tracking::Image<std::uint16_t>>> read_frame_files(const std::vector<fs::path>& files,
                                                                     const char* what, FrameSize* size) {
  const auto describe = [](int rows, int cols) {
    return std::to_string(cols) + " x " + std::to_string(rows);
  };
  for (const fs::path& f : files) {
    int rows = 0, cols = 0;
    if (Status s = drivers::frame_file_size(f.c_str(), &rows, &cols); !s.ok())
      return s.with_context(std::string(what) + " frame");
    if (size->rows == 0) {
      size->rows = rows;
      size->cols = cols;
      size->first = f;
    } else if (rows != size->rows || cols != size->cols) {
      return invalid_argument(std::string(what) + " frame " + f.string() + " is " + describe(rows, cols) +
                              " pixels; " + size->first.string() + " is " + describe(size->rows, size->cols) +
                              ": all frames must be one size");
    }
  }
  size->bytes += std::uint64_t(size->rows) * std::uint64_t(size->cols) * 2 * files.size();
  if (size->bytes > kMaxBytes)
    return invalid_argument("the frames would take more than 4 GiB of memory; use fewer frames");
  std::vector<tracking::Image<std::uint16_t>> frames;
  frames.reserve(files.size());
  for (const fs::path& f : files) {
    frames.emplace_back(size->rows, size->cols);
    if (Status s = drivers::read_frame_file(f.c_str(), frames.back().view()); !s.ok())
      return s.with_context(std::string(what) + " frame");
  }
  return frames;
}

}  // namespace lftrack::cli
