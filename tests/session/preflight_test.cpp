// The start-up checks (preflight.hpp) on scenes whose devices are not there: what each item says
// without any hardware. The checks against served devices are in
// tests/closed_loop/served_preflight_test.cpp.

#include <gtest/gtest.h>

#include <string>

#include "lftrack/host/preflight.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::host {
namespace {

// The built-in scene with both detectors' `frames: sim` replaced by `frames` (a '#' in it by the
// detector's number), each detector's `bits: 12` line preceded by `calibration` (a whole line, or
// nothing), and no actuator.
Result<PreparedScene> prepared(const std::string& frames, const std::string& calibration) {
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  char number = '1';
  for (std::size_t at = text.find("frames: sim"); at != std::string::npos; at = text.find("frames: sim", at + 1)) {
    std::string these = frames;
    if (const std::size_t hash = these.find('#'); hash != std::string::npos) these[hash] = number++;
    text.replace(at, 11, "frames: " + these);
    at += these.size();
  }
  for (std::size_t at = text.find("    bits: 12\n"); at != std::string::npos; at = text.find("    bits: 12\n", at + 1)) {
    text.insert(at, calibration);
    at += calibration.size();
  }
  text.replace(text.find("type: virtual"), 13, "type: none");
  auto scene = parse_scene(text, "room.yaml", "/srv/room");
  if (!scene.ok()) return scene.status();
  static tracking::ThreadPool pool(2);
  return prepare_scene(*scene, "", &pool);
}

const PreflightItem* item(const PreflightReport& r, const std::string& what) {
  for (const PreflightItem& i : r.items)
    if (i.what == what) return &i;
  return nullptr;
}

// `calibration: simulator` on a V4L2 panel: the simulator's detector model would correct a real
// panel's frames. Refused like a missing calibration (issue 50: it passed with a warning).
TEST(Preflight, TheSimulatorsCalibrationOnADeviceDetectorFails) {
  auto p = prepared("{type: v4l2, device: /dev/v4l/by-path/lftrack-test-absent-#}", "    calibration: simulator\n");
  ASSERT_TRUE(p.ok()) << p.status().message();
  const PreflightReport r = run_preflight(*p, LoopSessionOptions{}, RealtimeReport{}, true);
  for (const char* what : {"detector calibration of A", "detector calibration of B"}) {
    const PreflightItem* i = item(r, what);
    ASSERT_NE(i, nullptr) << r.checklist();
    EXPECT_EQ(i->result, CheckResult::kFail) << i->detail;
    EXPECT_NE(i->detail.find("calibration: simulator"), std::string::npos) << i->detail;
    EXPECT_NE(i->detail.find("lftrack calibrate detector"), std::string::npos) << "says what to do: " << i->detail;
  }
  EXPECT_FALSE(r.passed());
}

// Frames the simulator made (simulated detectors) take its model, as before: a warning.
TEST(Preflight, TheSimulatorsCalibrationOnSimulatedFramesWarns) {
  auto p = prepared("sim", "    calibration: simulator\n");
  ASSERT_TRUE(p.ok()) << p.status().message();
  const PreflightReport r = run_preflight(*p, LoopSessionOptions{}, RealtimeReport{}, true);
  const PreflightItem* i = item(r, "detector calibration of A");
  ASSERT_NE(i, nullptr) << r.checklist();
  EXPECT_EQ(i->result, CheckResult::kWarn) << i->detail;
}

}  // namespace
}  // namespace lftrack::host
