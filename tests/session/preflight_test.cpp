// The start-up checks (preflight.hpp) on scenes whose devices are not there: what each item says
// without any hardware. The checks against served devices are in
// tests/closed_loop/served_preflight_test.cpp.

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "actuator_lock_holder.hpp"
#include "lftrack/session/preflight.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/sim/tracker_twin.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using sim_devices::make_scene_patient;

using loop::ImagingSpec;
using loop::RealtimeReport;
namespace {

// The built-in scene with both detectors' `frames: sim` replaced by `frames` (a '#' in it by the
// detector's number), each detector's `bits: 12` line preceded by `calibration` (a whole line, or
// nothing), and no actuator.
Result<PreparedScene> prepared(const std::string& frames, const std::string& calibration,
                               const std::string& actuator = "type: none") {
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
  text.replace(text.find("type: virtual"), 13, actuator);
  auto scene = parse_scene(text, "room.yaml", "/srv/room");
  if (!scene.ok()) return scene.status();
  static tracking::ThreadPool pool(2);
  return prepare_scene(*scene, "", &pool);
}

// `lftrack run`'s options: the simulator given, for a room scene's simulated detectors.
LoopSessionOptions simulating() {
  LoopSessionOptions o;
  o.simulator = sim_devices::room_simulator();
  return o;
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
  const PreflightReport r = run_preflight(*p, simulating(), RealtimeReport{}, true);
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
  const PreflightReport r = run_preflight(*p, simulating(), RealtimeReport{}, true);
  const PreflightItem* i = item(r, "detector calibration of A");
  ASSERT_NE(i, nullptr) << r.checklist();
  EXPECT_EQ(i->result, CheckResult::kWarn) << i->detail;
}

// Without the simulator (a program that gives none), simulated detectors fail the checks, saying
// so, and the simulator's own checks (its frames' light fields) are not run (issue 55).
TEST(Preflight, SimulatedDetectorsWithoutTheSimulatorFail) {
  auto p = prepared("sim", "");
  ASSERT_TRUE(p.ok()) << p.status().message();
  p->scene.sim.renderer = "lightfield";
  const PreflightReport r = run_preflight(*p, LoopSessionOptions{}, RealtimeReport{}, true);
  const PreflightItem* i = item(r, "simulated detectors");
  ASSERT_NE(i, nullptr) << r.checklist();
  EXPECT_EQ(i->result, CheckResult::kFail) << i->detail;
  EXPECT_NE(i->detail.find("no"), std::string::npos) << i->detail;
  EXPECT_FALSE(r.passed());
  for (const PreflightItem& each : r.items)
    EXPECT_EQ(each.what.find("simulated frames"), std::string::npos)
        << "the simulator's check ran: " << each.what;
  const PreflightReport with = run_preflight(*p, simulating(), RealtimeReport{}, true);
  EXPECT_EQ(item(with, "simulated detectors"), nullptr) << with.checklist();
  bool frame_fields_checked = false;
  for (const PreflightItem& each : with.items)
    frame_fields_checked |= each.what.find("simulated frames") != std::string::npos;
  EXPECT_TRUE(frame_fields_checked) << "the simulator checks its frames' light fields: " << with.checklist();
}

// Simulated frames of the clinical preset from light fields (issue 51): preflight checks the fields
// of the day's water and bone, built by nothing but a session; missing, each fails and says what
// builds it, and nothing is written; once a session has built them, each passes.
TEST(Preflight, TheWaterAndBoneFieldsOfRealisticFramesAreCheckedNotBuilt) {
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  const std::string field = "  light_field:\n    resolution: [24, 24, 192, 192]\n";
  ASSERT_NE(text.find(field), std::string::npos) << "the built-in scene's sim.light_field changed";
  text.replace(text.find(field), field.size(), "  light_field:\n    resolution: [4, 4, 64, 64]\n  physics: clinical\n");
  auto scene = parse_scene(text, "room.yaml", "/srv/room");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  tracking::ThreadPool pool(2);
  auto p = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(p.ok()) << p.status().message();
  test::TempDir dir;
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.light_field_dir = dir.path();
  const auto sim_frames = dir.path() / "sim-frames";
  const PreflightReport before = run_preflight(*p, options, RealtimeReport{}, true);
  for (const char* material : {"water", "bone"}) {
    const PreflightItem* i =
        item(before, "light fields (simulated frames, " + std::string(material) + ") in " + (sim_frames / material).string());
    ASSERT_NE(i, nullptr) << before.checklist();
    EXPECT_EQ(i->result, CheckResult::kFail) << i->detail;
    EXPECT_NE(i->detail.find("lftrack precompute --scene " + p->scene.source + " -o " + dir.path().string()),
              std::string::npos)
        << "says what builds them: " << i->detail;
  }
  EXPECT_EQ(item(before, "light fields (simulated frames, attenuation) in " + (sim_frames / "attenuation").string()),
            nullptr)
      << "a spectrum images water and bone only";
  EXPECT_FALSE(std::filesystem::exists(sim_frames)) << "preflight builds nothing";
  ASSERT_TRUE(make_scene_patient(*p, dir.path(), &pool).ok());
  const PreflightReport after = run_preflight(*p, options, RealtimeReport{}, true);
  for (const char* material : {"water", "bone"}) {
    const PreflightItem* i =
        item(after, "light fields (simulated frames, " + std::string(material) + ") in " + (sim_frames / material).string());
    ASSERT_NE(i, nullptr) << after.checklist();
    EXPECT_EQ(i->result, CheckResult::kPass) << i->detail;
  }
}

}  // namespace
}  // namespace lftrack::session

namespace lftrack::session {
namespace {

// The actuator check opens the couch and tells it to hold: never under another program driving
// it (a treatment, a QA). Refused by the couch's lock, with the holder named, and not opened.
TEST(Preflight, TheActuatorCheckNeverOpensACouchAnotherProgramDrives) {
  test::TempDir locks;
  test::ScopedEnvironment lock_dir(kTestLockDirVariable, locks.path().string());
  // Nothing listens on port 1: an opened couch fails with the connection's error instead.
  auto p = prepared("sim", "", "type: modbus\n  modbus: {tcp: {host: 127.0.0.1, port: 1}}");
  ASSERT_TRUE(p.ok()) << p.status().message();
  const std::string what = "actuator (" + describe_actuator(p->scene.actuator) + ")";
  {
    test::ActuatorLockHolder treatment(p->scene);
    ASSERT_TRUE(treatment.held());
    const PreflightReport r = run_preflight(*p, simulating(), RealtimeReport{}, true);
    const PreflightItem* i = item(r, what);
    ASSERT_NE(i, nullptr) << r.checklist();
    EXPECT_EQ(i->result, CheckResult::kFail) << i->detail;
    EXPECT_NE(i->detail.find("driven by another lftrack"), std::string::npos) << i->detail;
    EXPECT_NE(i->detail.find("pid " + std::to_string(treatment.pid())), std::string::npos) << i->detail;
    EXPECT_NE(i->detail.find("not opened"), std::string::npos) << i->detail;
  }
  const PreflightReport free = run_preflight(*p, simulating(), RealtimeReport{}, true);
  const PreflightItem* i = item(free, what);
  ASSERT_NE(i, nullptr) << free.checklist();
  EXPECT_EQ(i->detail.find("driven by another lftrack"), std::string::npos)
      << "the lock was let go: " << i->detail;
  ::unsetenv("LFTRACK_TEST_LOCK_DIR");
}

}  // namespace
}  // namespace lftrack::session

namespace lftrack::session {
namespace {

const PreflightItem* surrogate_item(const PreflightReport& r) {
  for (const PreflightItem& i : r.items)
    if (i.what.rfind("breathing surrogate", 0) == 0) return &i;
  return nullptr;
}

// A run that images on demand from an optical tracker (surrogate.source igtl): the checklist
// connects and waits for readings of the scene's device (issue 58 probe: `run --check` said
// nothing of the tracker, and a run started without a single reading).
TEST(Preflight, TheOpticalTrackerIsConnectedAndStreamingItsMarker) {
  auto p = prepared("sim", "");
  ASSERT_TRUE(p.ok()) << p.status().message();
  sim::TrackerTwinOptions twin;
  twin.rate_hz = 100;
  auto tracker = sim::TrackerTwin::start(twin, [](std::int64_t, Eigen::Vector3d* position) {
    *position = Eigen::Vector3d(0, 0, 4.5);
    return true;
  });
  ASSERT_TRUE(tracker.ok()) << tracker.status().message();
  p->scene.loop.imaging.mode = ImagingSpec::Mode::kModel;
  p->scene.surrogate.source = "igtl";
  p->scene.surrogate.igtl_port = (*tracker)->port();
  p->scene.surrogate.igtl_device = "Marker";
  p->scene.loop.imaging.surrogate.stale_ms = 5000;  // a loaded host may hold a reading a while
  LoopSessionOptions o;
  o.simulator = sim_devices::room_simulator();
  o.devices = SessionDevices::kScene;
  const PreflightItem* i = nullptr;
  {
    const PreflightReport r = run_preflight(*p, o, RealtimeReport{}, true);
    i = surrogate_item(r);
    ASSERT_NE(i, nullptr) << r.checklist();
    EXPECT_EQ(i->result, CheckResult::kPass) << i->detail;
    EXPECT_NE(i->detail.find("readings in"), std::string::npos) << i->detail;
    EXPECT_NE(i->detail.find("4.5 mm"), std::string::npos) << i->detail;
  }
  p->scene.surrogate.igtl_device = "Probe";  // the marker is not on the stream
  {
    const PreflightReport r = run_preflight(*p, o, RealtimeReport{}, true);
    i = surrogate_item(r);
    ASSERT_NE(i, nullptr) << r.checklist();
    EXPECT_EQ(i->result, CheckResult::kFail) << i->detail;
    EXPECT_NE(i->detail.find("other devices"), std::string::npos) << i->detail;
    EXPECT_NE(i->detail.find("\"Marker\""), std::string::npos) << "names what came instead: " << i->detail;
  }
  tracker->reset();  // the tracker's server is gone
  {
    const PreflightReport r = run_preflight(*p, o, RealtimeReport{}, true);
    i = surrogate_item(r);
    ASSERT_NE(i, nullptr) << r.checklist();
    EXPECT_EQ(i->result, CheckResult::kFail) << i->detail;
    EXPECT_NE(i->detail.find("is it running"), std::string::npos) << i->detail;
  }
}

}  // namespace
}  // namespace lftrack::session
