// Light-field folders as a user shares them (issue 50): two scenes that differ only in their
// geometry, or only in their CT, keep their own fields in one --lf-dir, and `precompute` builds
// nothing that is up to date.

#include <gtest/gtest.h>

#include <fstream>
#include <iterator>
#include <map>

#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"  // run_process
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

namespace fs = std::filesystem;

// The built-in phantom with a small field; `from`, `to`: one line changed. Its simulated frames
// are Siddon's (no fields of their own) unless `sim_fields`, which makes those small too.
fs::path scene_file(const fs::path& dir, const std::string& name, const std::string& from = "",
                    const std::string& to = "", bool sim_fields = false) {
  std::string scene = *builtin_scene_text(kBuiltinPhantom);
  const std::string field = "    resolution: [16, 16, 128, 128]\n";
  scene.replace(scene.find(field), field.size(), "    resolution: [4, 4, 48, 48]\n");
  const std::string sim =
      "  renderer: lightfield    # frames from a separate, finer field of the anatomy\n"
      "  light_field:\n    resolution: [24, 24, 192, 192]\n";
  EXPECT_NE(scene.find(sim), std::string::npos);
  scene.replace(scene.find(sim), sim.size(),
                sim_fields ? "  renderer: lightfield\n  light_field:\n    resolution: [4, 4, 64, 64]\n"
                           : "  renderer: siddon\n");
  if (!from.empty()) {
    EXPECT_NE(scene.find(from), std::string::npos) << from;
    scene.replace(scene.find(from), from.size(), to);
  }
  const fs::path file = dir / (name + ".yaml");
  std::ofstream(file) << scene;
  return file;
}

// Every file of `dir` with its bytes.
std::map<std::string, std::string> folder(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& e : fs::directory_iterator(dir)) {
    std::ifstream in(e.path(), std::ios::binary);
    files[e.path().filename().string()] = {std::istreambuf_iterator<char>(in), {}};
  }
  return files;
}

int count(const std::string& text, const std::string& word) {
  int n = 0;
  for (auto at = text.find(word); at != std::string::npos; at = text.find(word, at + 1)) ++n;
  return n;
}

TEST(Cli, ScenesSharingALightFieldFolderKeepTheirFieldsAndPrecomputeSkipsThoseUpToDate) {
  test::TempDir dir;
  const fs::path lf = dir.path() / "lf";
  const fs::path patient = scene_file(dir.path(), "patient");
  const fs::path wider = scene_file(dir.path(), "wider", "rotation_deg: 5", "rotation_deg: 6");
  const fs::path other_ct = scene_file(dir.path(), "other-ct", "  seed: 1\n", "  seed: 2\n");
  auto precompute = [&](const fs::path& scene) {
    std::string out;
    EXPECT_TRUE(run_process({LFTRACK_BIN_PATH, "precompute", "--scene", scene.string(), "-o", lf.string()}, &out).ok())
        << out;
    return out;
  };
  std::string out = precompute(patient);
  EXPECT_EQ(count(out, ": built\n"), 2) << out;
  const auto patients = folder(lf);
  ASSERT_EQ(patients.size(), 2u);
  for (const fs::path& other : {wider, other_ct}) {
    out = precompute(other);
    EXPECT_EQ(count(out, ": built\n"), 2) << other << ": " << out;
  }
  const auto all = folder(lf);
  EXPECT_EQ(all.size(), 6u);
  for (const auto& [name, bytes] : patients) EXPECT_EQ(all.at(name), bytes) << name << " was replaced";
  // Each scene again: every field up to date, nothing built or written.
  for (const fs::path& scene : {patient, wider, other_ct}) {
    out = precompute(scene);
    EXPECT_EQ(count(out, ": up to date\n"), 2) << scene << ": " << out;
    EXPECT_EQ(count(out, ": built\n"), 0) << scene << ": " << out;
  }
  EXPECT_EQ(folder(lf), all);
}

// A scene whose simulated frames come from light fields: `precompute` builds the simulator's
// fields too (in <folder>/sim-frames), so that the room's loop (`sim --room`) finds every field it checks
// for, and a second precompute writes nothing.
TEST(Cli, PrecomputeBuildsTheSimulatorsFrameFieldsWhereTheSceneDrawsFramesFromThem) {
  test::TempDir dir;
  const fs::path lf = dir.path() / "lf";
  const fs::path scene = scene_file(dir.path(), "room", "", "", true);
  std::string out;
  auto check = [&] {
    std::string checklist;
    (void)run_process({LFTRACK_BIN_PATH, "sim", "--room", "--check", "--rt", "ignore", "--scene",
                       scene.string(), "--lf-dir", lf.string()},
                      &checklist);
    return checklist;
  };
  const std::string before = check();
  EXPECT_NE(before.find("[FAIL] light fields (simulated frames) in " + (lf / "sim-frames").string()),
            std::string::npos)
      << before;
  EXPECT_NE(
      before.find("build them first: lftrack precompute --scene " + scene.string() + " -o " + lf.string()),
      std::string::npos)
      << before;
  ASSERT_TRUE(
      run_process({LFTRACK_BIN_PATH, "precompute", "--scene", scene.string(), "-o", lf.string()}, &out).ok())
      << out;
  EXPECT_EQ(count(out, ": built\n"), 2) << out;
  EXPECT_NE(out.find((lf / "sim-frames").string() + ": 2 built"), std::string::npos) << out;
  const auto fields = folder(lf / "sim-frames");
  EXPECT_EQ(fields.size(), 2u) << "one field per view";
  const std::string after = check();
  EXPECT_NE(after.find("[ ok ] light fields (simulated frames) in " + (lf / "sim-frames").string()),
            std::string::npos)
      << after;
  EXPECT_NE(after.find("[ ok ] light fields (tracking)"), std::string::npos) << after;
  ASSERT_TRUE(
      run_process({LFTRACK_BIN_PATH, "precompute", "--scene", scene.string(), "-o", lf.string()}, &out).ok())
      << out;
  EXPECT_EQ(folder(lf / "sim-frames"), fields) << "a second precompute rewrote the simulator's fields";
  EXPECT_NE(out.find((lf / "sim-frames").string() + ": up to date"), std::string::npos) << out;
}

}  // namespace
}  // namespace lftrack::session
