#pragma once
// Small helpers the command-line tests share: the program's path, a shell-quoted argument, a
// file's whole text, and a finished run's exit code and output.

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace lftrack::test {

#ifdef LFTRACK_BIN_PATH
// The `lftrack` program this build made (each suite's LFTRACK_BIN_PATH).
inline std::string lftrack_bin() { return LFTRACK_BIN_PATH; }
#endif

// `s` as one POSIX shell word: single-quoted, each ' written as '\''.
inline std::string quoted(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

// The bytes of `file`; empty when it cannot be read.
inline std::string contents(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

// A finished command: its exit code (-1 when it did not exit normally) and its output.
struct CliRun {
  int exit_code = -1;
  std::string out;  // stdout and stderr
};

}  // namespace lftrack::test
