// `lftrack bench frames` as a user runs it (issue 51): the simulator's frame pairs rendered by
// Siddon and by light fields, side by side, with the clinical preset (water and bone fields of
// their own) and with ideal frames; absurd options refused.

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

namespace fs = std::filesystem;
using test::lftrack_bin;

// The built-in scene with small frame fields (built in seconds), `physics` its sim.physics; empty
// if the built-in scene's sim.light_field is no longer the one this edits.
fs::path phantom_scene(const fs::path& dir, const std::string& physics) {
  std::string scene = *builtin_scene_text(kBuiltinPhantom);
  const std::string field = "  light_field:\n    resolution: [24, 24, 192, 192]\n";
  const auto at = scene.find(field);
  if (at == std::string::npos) return {};
  scene.replace(at, field.size(), "  light_field:\n    resolution: [4, 4, 128, 128]\n  physics: " + physics + "\n");
  const fs::path file = dir / ("phantom-" + physics + ".yaml");
  std::ofstream(file) << scene;
  return file;
}

nlohmann::json bench(const fs::path& scene, const fs::path& lf, std::string* out) {
  const Status s = run_process({lftrack_bin(), "-q", "bench", "frames", "--scene", scene.string(), "--pairs", "3",
                                "--lf-dir", lf.string(), "--json"},
                               out);
  EXPECT_TRUE(s.ok()) << *out;
  const auto brace = out->find('{');
  if (!s.ok() || brace == std::string::npos) return {};
  return nlohmann::json::parse(out->substr(brace));
}

TEST(BenchFramesCli, ClinicalFramesFromLightFieldsAreSiddonsFramesAndBothAreTimed) {
  test::TempDir dir;
  const fs::path scene = phantom_scene(dir.path(), "clinical");
  ASSERT_FALSE(scene.empty()) << "the built-in scene's sim.light_field changed";
  std::string out;
  const auto j = bench(scene, dir.path() / "lf", &out);
  ASSERT_TRUE(j.contains("renderers")) << out;
  EXPECT_EQ(j["pairs"], 3);
  EXPECT_NE(j["physics"].get<std::string>().find("scatter"), std::string::npos) << j["physics"];
  ASSERT_EQ(j["renderers"].size(), 2u);
  EXPECT_EQ(j["renderers"][0]["renderer"], "siddon");
  EXPECT_EQ(j["renderers"][1]["renderer"], "lightfield");
  for (const auto& r : j["renderers"]) {
    EXPECT_GT(r["pair_ms"]["median"].get<double>(), 0.0) << r["renderer"];
    EXPECT_LE(r["pair_ms"]["min"].get<double>(), r["pair_ms"]["median"].get<double>()) << r["renderer"];
    EXPECT_LE(r["pair_ms"]["median"].get<double>(), r["pair_ms"]["p95"].get<double>()) << r["renderer"];
    // The whole detectors: more pixels than the windows, each pair timed beside the windows'.
    EXPECT_GT(r["whole_detector_pixels"].get<std::int64_t>(), r["exposed_pixels"].get<std::int64_t>()) << r["renderer"];
    EXPECT_GT(r["whole_pair_ms"]["median"].get<double>(), 0.0) << r["renderer"];
    EXPECT_GT(r["speedup_vs_siddon"].get<double>(), 0.0) << r["renderer"];
  }
  // Siddon exposes a margin around each ROI, a light field the ROI alone.
  EXPECT_GT(j["renderers"][0]["exposed_pixels"].get<int>(), j["renderers"][1]["exposed_pixels"].get<int>());
  // Expected counts (no photon noise) through the same water, bone, scatter and detector (JSON has
  // no NaN: a non-finite figure would be null and fail get<double>()).
  ASSERT_TRUE(j["renderers"][1]["ncc_vs_siddon"].is_number()) << out;
  EXPECT_GT(j["renderers"][1]["ncc_min_vs_siddon"].get<double>(), 0.98) << out;
  // The day's water and bone have fields of their own, one per view.
  for (const char* material : {"water", "bone"}) {
    int files = 0;
    for (const auto& e : fs::directory_iterator(dir.path() / "lf" / "sim-frames" / material))
      files += e.path().extension() == ".lf";
    EXPECT_EQ(files, 2) << material;
  }
}

TEST(BenchFramesCli, IdealFramesUseTheWorldAnatomysFieldAndAbsurdOptionsAreRefused) {
  test::TempDir dir;
  const fs::path scene = phantom_scene(dir.path(), "ideal");
  ASSERT_FALSE(scene.empty()) << "the built-in scene's sim.light_field changed";
  std::string out;
  const auto j = bench(scene, dir.path() / "lf", &out);
  ASSERT_TRUE(j.contains("renderers")) << out;
  EXPECT_GT(j["renderers"][1]["ncc_min_vs_siddon"].get<double>(), 0.98) << out;
  EXPECT_FALSE(fs::exists(dir.path() / "lf" / "sim-frames" / "water")) << "ideal frames image no water and bone";
  for (const char* pairs : {"0", "-1", "nan", "1e12"}) {
    EXPECT_FALSE(run_process({lftrack_bin(), "-q", "bench", "frames", "--scene", scene.string(), "--pairs", pairs},
                             &out)
                     .ok())
        << pairs;
    EXPECT_NE(out.find("--pairs"), std::string::npos) << pairs << ": " << out;
  }
  EXPECT_FALSE(run_process({lftrack_bin(), "-q", "bench", "frames", "--scene", (dir.path() / "none.yaml").string()},
                           &out)
                   .ok());
  EXPECT_NE(out.find("none.yaml"), std::string::npos) << out;
}

}  // namespace
}  // namespace lftrack::session
