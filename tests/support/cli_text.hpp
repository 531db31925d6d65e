#pragma once
// Small helpers the command-line tests share: the program's path, a shell-quoted argument, a
// file's whole text, a finished run's exit code and output, and the built-in scene with coarse or
// tiny light fields.

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include "lftrack/session/scene.hpp"

namespace lftrack::test {

// The built-in scene's text with a coarse light field (built in a few seconds), for command tests.
inline std::string coarse_phantom_scene_text() {
  std::string scene = *session::builtin_scene_text(session::kBuiltinPhantom);
  const std::string field = "    resolution: [16, 16, 128, 128]\n";
  scene.replace(scene.find(field), field.size(), "    resolution: [8, 8, 96, 96]\n");
  return scene;
}

// The built-in scene's text with tiny light fields, the registration's and the simulated frames'
// (6 x 6 x 48 x 64: built in about a second), for command tests that run the loop.
inline std::string tiny_field_phantom_scene_text() {
  std::string scene = *session::builtin_scene_text(session::kBuiltinPhantom);
  for (const std::string field :
       {"    resolution: [16, 16, 128, 128]\n", "    resolution: [24, 24, 192, 192]\n"})
    scene.replace(scene.find(field), field.size(), "    resolution: [6, 6, 48, 64]\n");
  return scene;
}

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
