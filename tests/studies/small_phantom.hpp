#pragma once
// A scene the studies' tests run in seconds: the built-in phantom on 128 x 128 detectors of
// 1.6 mm (a quarter of its pixels each way) with a 4 x 4 x 48 x 48 light field.

#include <string>

#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_verdict.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::test {

// `floor` > 0: the scene says safety.min_similarity: floor (in its measure's units, mi).
inline Result<session::PreparedScene> small_phantom(tracking::ThreadPool* pool, double floor = 0) {
  std::string text = *session::builtin_scene_text("builtin:phantom");
  const auto swap_all = [&](const std::string& from, const std::string& to) {
    for (auto at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size()))
      text.replace(at, from.size(), to);
  };
  swap_all("    rows: 512\n", "    rows: 128\n");
  swap_all("    cols: 512\n", "    cols: 128\n");
  swap_all("    pitch_mm: 0.4\n", "    pitch_mm: 1.6\n");
  swap_all("    resolution: [16, 16, 128, 128]\n", "    resolution: [4, 4, 48, 48]\n");
  if (floor > 0) swap_all("safety:\n", "safety:\n  min_similarity: " + std::to_string(floor) + "\n");
  auto scene = session::parse_scene(text, "small-phantom.yaml", ".");
  if (!scene.ok()) return scene.status();
  return session::prepare_scene(*scene, "", pool);
}

}  // namespace lftrack::test
