#pragma once
// A study's output folder: nothing an earlier study (or anyone) left there under the names this
// study writes is ever replaced.

#include <filesystem>

#include "lftrack/tracking/status.hpp"

namespace lftrack::studies {

// Refuses, naming the first, any of `names` already in `out_dir` (a file, a folder or a link,
// dangling or not); nothing is written either way.
template <std::size_t N>
Status refuse_existing_outputs(const std::filesystem::path& out_dir, const char* const (&names)[N]) {
  std::error_code ec;
  for (const char* name : names)
    if (std::filesystem::exists(out_dir / name, ec) || std::filesystem::is_symlink(out_dir / name, ec))
      return failed_precondition(
          (out_dir / name).string() +
          " exists (an earlier study's, or another file): give another --out (nothing was "
          "written)");
  return {};
}

}  // namespace lftrack::studies
