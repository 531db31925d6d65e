// `lftrack calibrate views` and `lftrack calibrate couch` as a user runs them: the simulated
// room's geometry and a misaligned couch recovered, the files a scene then uses, and bad input
// refused with a reason.

#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/session/calibration_files.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"  // run_process
#include "lftrack/tracking/image_io.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

using test::lftrack_bin;

// The built-in scene with `extra` appended to its actuator section.
std::string builtin_with_actuator_lines(const std::string& extra) {
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  const std::string anchor = "  max_speed_deg_s: 10\n";
  text.insert(text.find(anchor) + anchor.size(), extra);
  return text;
}

TEST(Cli, CalibrateViewsRecoversTheSimulatedRoomAndWritesADetectorSection) {
  test::TempDir dir;
  const auto file = dir.path() / "detectors.yaml";
  std::string out;
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "calibrate", "views", "--sim", "--seed", "1", "--json",
                           "--out", file.string(), "--save-images", dir.path().string()},
                          &out)
                  .ok())
      << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_LT(j["source_error_mm"].get<double>(), 0.1);
  EXPECT_LT(j["detector_error_mm"].get<double>(), 0.1);
  EXPECT_LT(j["orientation_error_deg"].get<double>(), 0.02);
  EXPECT_LT(j["rms_px"].get<double>(), 0.05);
  // The written section replaces the scene's detectors and parses.
  std::ifstream in(file);
  const std::string written((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string section =
      written.substr(written.find("detectors:"), written.find("calibration:") - written.find("detectors:"));
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  const std::size_t from = text.find("detectors:"), to = text.find("envelope:");
  text.replace(from, to - from, section);
  auto scene = parse_scene(text, file.string(), dir.path());
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  ASSERT_EQ(scene->detectors.size(), 2u);
  auto builtin = load_scene(kBuiltinPhantom);
  ASSERT_TRUE(builtin.ok());
  EXPECT_LT((scene->detectors[1].view.source_mm - builtin->detectors[1].view.source_mm).norm(), 0.1);
  // The saved images calibrate to the same geometry from files.
  std::string again;
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "calibrate", "views", "--images",
                           (dir.path() / "phantom_A.pfm").string(), (dir.path() / "phantom_B.pfm").string(),
                           "--json"},
                          &again)
                  .ok())
      << again;
  const auto k = nlohmann::json::parse(again.substr(again.find('{')));
  // The files hold float32 line integrals: the same geometry to within their rounding.
  EXPECT_NEAR(k["views"][0]["source_mm"][0].get<double>(), j["views"][0]["source_mm"][0].get<double>(), 0.02);
}

TEST(Cli, CalibrateViewsRefusesBadInputWithAReason) {
  test::TempDir dir;
  std::string out;
  EXPECT_FALSE(run_process({lftrack_bin(), "calibrate", "views"}, &out).ok());
  EXPECT_NE(out.find("--images"), std::string::npos) << out;
  const auto small = dir.path() / "small.pfm";
  ASSERT_TRUE(tracking::write_image(small, tracking::Image<float>(64, 64, 0.2f).view(), {}).ok());
  EXPECT_FALSE(
      run_process({lftrack_bin(), "calibrate", "views", "--images", small.string(), small.string()}, &out)
          .ok());
  EXPECT_NE(out.find("64 x 64"), std::string::npos) << out;
  const auto phantom = dir.path() / "flat.yaml";
  std::ofstream(phantom) << "markers_mm:\n  - [0, 0, 0]\n  - [10, 0, 0]\n";
  EXPECT_FALSE(
      run_process({lftrack_bin(), "calibrate", "views", "--sim", "--phantom", phantom.string()}, &out).ok());
  EXPECT_NE(out.find("at least 6 markers"), std::string::npos) << out;
}

TEST(Cli, CalibrateCouchRecoversAMisalignedCouchAndASceneUsesTheFile) {
  test::TempDir dir;
  const auto scene = dir.path() / "mounted.yaml";
  std::ofstream(scene) << builtin_with_actuator_lines(
      "  mounting: {rotation_deg: [1, 1, 1], centre_mm: [5, -30, 200]}\n");
  const auto calibration = dir.path() / "couch.yaml";
  std::string out;
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "calibrate", "couch", "--scene", scene.string(), "--out",
                           calibration.string(), "--json"},
                          &out)
                  .ok())
      << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_LT(j["rotation_error_deg"].get<double>(), 0.05);
  EXPECT_LT(j["centre_error_mm"].get<double>(), 0.5);
  EXPECT_EQ(j["moves"].get<int>(), 12);
  // A scene names the file; it loads with the recovered mounting.
  const auto using_it = dir.path() / "calibrated.yaml";
  std::ofstream(using_it) << builtin_with_actuator_lines("  calibration: couch.yaml\n");
  auto loaded = load_scene(using_it.string());
  ASSERT_TRUE(loaded.ok()) << loaded.status().message();
  ASSERT_TRUE(loaded->actuator.calibration.has_value());
  EXPECT_NEAR(tracking::rad_to_deg(loaded->actuator.calibration->rotation_rad.x()), 1.0, 0.05);
  EXPECT_NEAR(loaded->actuator.calibration->centre_room_mm->z(), 200, 0.5);
  // A missing or malformed calibration file fails at load with the scene's line.
  std::ofstream(using_it) << builtin_with_actuator_lines("  calibration: nowhere.yaml\n");
  auto missing = load_scene(using_it.string());
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("nowhere.yaml"), std::string::npos) << missing.status().message();
  std::ofstream(dir.path() / "bad.yaml") << "couch_calibration: {rotation_deg: [1, 2]}\n";
  std::ofstream(using_it) << builtin_with_actuator_lines("  calibration: bad.yaml\n");
  EXPECT_FALSE(load_scene(using_it.string()).ok());
  // Moves outside the couch's range are refused.
  const auto moves = dir.path() / "moves.yaml";
  std::ofstream(moves) << "moves:\n  - {translation_mm: [80, 0, 0]}\n  - {translation_mm: [0, 5, 0]}\n"
                          "  - {rotation_deg: [0, 0, 1]}\n";
  EXPECT_FALSE(
      run_process({lftrack_bin(), "calibrate", "couch", "--scene", scene.string(), "--moves", moves.string()},
                  &out)
          .ok());
  EXPECT_NE(out.find("range"), std::string::npos) << out;
}

// --out never replaces a file unasked, and with --overwrite only an earlier couch calibration:
// each refusal comes before the couch is moved, and leaves the file as it was.
TEST(Cli, CalibrateCouchNeverReplacesAFileUnasked) {
  test::TempDir dir;
  const auto calibration = dir.path() / "couch.yaml";
  std::string out;
  ASSERT_TRUE(
      run_process({lftrack_bin(), "-q", "calibrate", "couch", "--out", calibration.string(), "--seed", "1"},
                  &out)
          .ok())
      << out;
  const std::string earlier = test::contents(calibration);
  ASSERT_FALSE(earlier.empty());
  EXPECT_FALSE(
      run_process({lftrack_bin(), "-q", "calibrate", "couch", "--out", calibration.string()}, &out).ok());
  EXPECT_NE(out.find("--overwrite"), std::string::npos) << "says how to replace it: " << out;
  EXPECT_EQ(test::contents(calibration), earlier) << "the earlier file is as it was";
  const auto scene = dir.path() / "scene.yaml";
  std::ofstream(scene) << builtin_with_actuator_lines("");
  const std::string scene_text = test::contents(scene);
  EXPECT_FALSE(
      run_process({lftrack_bin(), "-q", "calibrate", "couch", "--out", scene.string(), "--overwrite"}, &out)
          .ok());
  EXPECT_NE(out.find("not a couch calibration"), std::string::npos) << out;
  EXPECT_EQ(test::contents(scene), scene_text) << "a scene named by an --out typo is never replaced";
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "calibrate", "couch", "--out", calibration.string(),
                           "--overwrite", "--seed", "2"},
                          &out)
                  .ok())
      << out;
  EXPECT_NE(test::contents(calibration), earlier)
      << "replaced with --overwrite (another seed, other figures)";
  EXPECT_TRUE(read_couch_calibration(calibration.string()).ok());
}

}  // namespace
}  // namespace lftrack::session
