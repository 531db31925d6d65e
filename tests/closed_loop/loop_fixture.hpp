#pragma once
// The closed-loop tests' scene and fixture: a small version of the built-in scene (0.8 mm
// detector pixels, small light fields; frames from a separate finer field, or ray-cast), run on
// the simulated clock through a LoopSession with a journal.

#include <gtest/gtest.h>

#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <thread>

#include "lftrack/drivers/forwarding_actuator.hpp"
#include "lftrack/records/journal_reader.hpp"
#include "lftrack/records/loop_json.hpp"
#include "lftrack/session/loop_session.hpp"
#include "lftrack/session/scene_fingerprint.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::session {

inline const char* kLightFieldFrames =
    "sim:\n  renderer: lightfield\n  light_field:\n    resolution: [16, 16, 96, 144]\n";
inline const char* kRayCastFrames = "sim:\n  renderer: siddon\n";
inline const char* kBreathing =
    "motion:\n  setup_error: {translation_mm: [3, -2, 2], rotation_deg: [1, -0.5, 1]}\n"
    "  drift: {translation_mm_per_s: [0.02, 0.01, -0.02]}\n"
    "  breathing: {amplitude_mm: [0.5, 1.5, 4.5], period_s: 4}\n";

// The built-in scene with 0.8 mm detector pixels (a quarter of the rays), the frames' renderer
// and the motion given: its text (for a server in another process) and the scene.
inline std::string small_scene_text(const std::string& motion_yaml, const std::string& frames_yaml) {
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  for (const char* from : {"    rows: 512\n    cols: 512\n    pitch_mm: 0.4\n"}) {
    for (std::size_t at = text.find(from); at != std::string::npos; at = text.find(from))
      text.replace(at, std::string(from).size(), "    rows: 256\n    cols: 256\n    pitch_mm: 0.8\n");
  }
  const auto cut = [&](const std::string& key) {
    const std::size_t at = text.find(key);
    if (at != std::string::npos) text.erase(at);
  };
  cut("tracking:");  // everything from here on is replaced
  text +=
      "tracking:\n  renderer: lightfield\n  light_field:\n    resolution: [12, 12, 64, 96]\n  similarity: "
      "mi\n" +
      frames_yaml + "  photons_per_pixel: 20000\n  detector_blur_px: 0.5\n" +
      "loop:\n  period_ms: 100\n  registration_budget_ms: 50\n  acquire_timeout_ms: 40\n"
      "actuator:\n  type: virtual\n  latency_s: 0.1\n  max_speed_mm_s: 40\n  max_speed_deg_s: 10\n" +
      motion_yaml;
  return text;
}

inline Scene small_scene(const std::string& motion_yaml, const std::string& frames_yaml) {
  const std::string text = small_scene_text(motion_yaml, frames_yaml);
  auto scene = parse_scene(text, "small-closed-loop.yaml", std::filesystem::current_path());
  EXPECT_TRUE(scene.ok()) << scene.status().message();
  return *scene;
}

// A run that should track every cycle: every cycle ends in TRACK, with no HOLD or FAULT; on
// failure the summary (with the transitions and their reasons) is printed.
inline void expect_tracks_every_cycle(const loop::LoopSummary& s, std::int64_t cycles) {
  SCOPED_TRACE(records::to_json(s).dump());
  EXPECT_EQ(s.cycles, cycles);
  EXPECT_EQ(s.states[std::size_t(loop::TrackingState::kTrack)], cycles);
  EXPECT_EQ(s.holds, 0);
  EXPECT_EQ(s.faults, 0);
}

// The light-field folder for `p`, shared by every test process (test::test_cache_dir()): the
// first run that needs the fields builds and saves them (each file written whole, then renamed
// into place, so a concurrent reader sees all of a file or none), later runs load them. Loading
// checks each field against the CT's and the plan's hashes, so a field from another scene is
// rebuilt, never used. The folder is named after the CT, both plans and the lftrack build (the
// program's modification time: the hashes do not cover the code that samples a field, so a
// rebuilt lftrack builds its fields anew), so the few tests that change the plan (the envelope)
// do not rebuild the others' fields.
inline std::filesystem::path shared_light_field_dir(const PreparedScene& p) {
  std::uint64_t key = 0;
  for (int i = 0; i < int(p.scene.detectors.size()); ++i)
    key = key * 1000003u ^ tracking::plan_hash(p.light_field_plan(i), p.scene.light_field);
  std::error_code ec;
  const auto built = std::filesystem::last_write_time(LFTRACK_BIN_PATH, ec);
  key = key * 1000003u ^ static_cast<std::uint64_t>(ec ? 0 : built.time_since_epoch().count());
  const auto& r = p.scene.sim.light_field.resolution;
  char name[96];
  std::snprintf(name, sizeof name, "%s-%016llx-sim%dx%dx%dx%d", to_hex(scene_fingerprint(p.scene)).c_str(),
                static_cast<unsigned long long>(key), r[0], r[1], r[2], r[3]);
  return test::test_cache_dir() / "closed-loop-light-fields" / name;
}

struct LoopRun {
  loop::LoopSummary summary;
  records::JournalContents journal;
};

class ClosedLoop : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { pool_ = new tracking::ThreadPool(2); }
  static void TearDownTestSuite() { delete pool_; }

  // `during_run`, if given, starts a thread on the created session (fault injection), joined
  // when the loop has ended and before the session is destroyed.
  LoopRun run_loop(const std::string& motion_yaml, std::int64_t cycles, LoopSessionOptions options = {},
                   const std::string& frames_yaml = kLightFieldFrames,
                   const std::function<std::thread(LoopSession&)>& during_run = {}) {
    Scene scene = small_scene(motion_yaml, frames_yaml);
    if (edit_scene_) edit_scene_(scene);
    auto prepared = prepare_scene(scene, "", pool_);
    EXPECT_TRUE(prepared.ok()) << prepared.status().message();
    scene_ = std::make_unique<PreparedScene>(std::move(prepared).value());
    options.cycles = cycles;
    if (options.simulator == nullptr) options.simulator = sim_devices::room_simulator();
    options.simulated_clock = !real_clock_;
    options.light_field_dir = shared_light_field_dir(*scene_);
    // A journal of its own per run (journals are never overwritten).
    if (options.journal.empty()) options.journal = dir_.path() / ("journal-" + std::to_string(++runs_) + ".lfj");
    auto session = LoopSession::create(*scene_, options, pool_);
    LoopRun r;
    EXPECT_TRUE(session.ok()) << session.status().message();
    if (!session.ok()) return r;
    std::thread during;
    if (during_run) during = during_run(**session);
    auto summary = (*session)->run();
    if (during.joinable()) during.join();
    EXPECT_TRUE(summary.ok()) << summary.status().message();
    if (!summary.ok()) return r;
    r.summary = *summary;
    auto journal = records::read_journal(options.journal);
    EXPECT_TRUE(journal.ok()) << journal.status().message();
    if (journal.ok()) {  // what `journal export --dicom-sro` checks the scene by
      EXPECT_EQ(journal->scene_fingerprint, scene_fingerprint(scene_->scene));
    }
    r.journal = *journal;
    return r;
  }

  // The shared light-field folder of the fixture's scene (prepares it: the CT takes a few seconds).
  std::filesystem::path small_scene_light_field_dir() {
    auto prepared = prepare_scene(small_scene(kBreathing, kLightFieldFrames), "", pool_);
    EXPECT_TRUE(prepared.ok()) << prepared.status().message();
    return prepared.ok() ? shared_light_field_dir(*prepared) : dir_.path() / "light-fields";
  }

  int runs_ = 0;                             // loops run by this test
  bool real_clock_ = false;                  // on the real clock (devices in other processes)
  std::function<void(Scene&)> edit_scene_;  // applied to the scene before each run, if set
  static inline tracking::ThreadPool* pool_ = nullptr;
  test::TempDir dir_;
  std::unique_ptr<PreparedScene> scene_;
};

}  // namespace lftrack::session
