#pragma once
// What every fuzz target shares: the input written to a file of this process's own (readers
// under test take paths), and a check that a refusal says why.
//
// A target returns 0 for every input; a crash, a sanitizer report, a leak or a timeout is the
// finding. Targets never print: libFuzzer's own output is the report.

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "lftrack/tracking/status.hpp"

namespace lftrack::fuzz {

// A folder of this process's own under $TMPDIR (or /tmp), made once.
inline const std::filesystem::path& scratch() {
  static const std::filesystem::path dir = [] {
    const char* tmp = std::getenv("TMPDIR");
    std::filesystem::path d =
        std::filesystem::path(tmp != nullptr ? tmp : "/tmp") / ("lftrack-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    return d;
  }();
  return dir;
}

inline std::filesystem::path write_input(const std::string& name, const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path file = scratch() / name;
  std::ofstream(file, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return file;
}

// A refusal must carry a reason: an empty message is a finding too.
inline void expect_reason(const Status& s) {
  if (!s.ok() && s.message().empty()) std::abort();
}

}  // namespace lftrack::fuzz
