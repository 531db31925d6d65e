// Imaging on demand in a scene (issue 58): tracking.imaging and the surrogate section, refused
// where they make no sense; the dose model's numbers; the simulated chest marker's readings and
// faults.
#include <gtest/gtest.h>

#include <cmath>

#include "lftrack/session/loop_session.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_imaging_dose.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "lftrack/sim_devices/sim_surrogate_source.hpp"

namespace lftrack::session {

using sim_devices::SimSurrogateSource;

using loop::CorrelationModelSpec;
using loop::ImagingSpec;
namespace {

std::string imaging_scene(const std::string& extra) {
  return R"(version: 1
ct: {path: ct_folder}
roi: {centre_mm: [0, 0, 0]}
detectors:
  - name: A
    rows: 64
    cols: 64
    pitch_mm: 0.4
    isocentric: {source_direction: [0, -1, 0], up: [0, 0, 1], source_to_isocentre_mm: 1000, source_to_detector_mm: 1500}
motion:
  breathing: {amplitude_mm: [0, 0, 8], period_s: 5}
)" + extra;
}

Result<Scene> parse(const std::string& extra) {
  return parse_scene(imaging_scene(extra), "s.yaml", "/");
}

TEST(SceneImaging, EveryCycleByDefault) {
  auto scene = parse("");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_FALSE(scene->loop.imaging.model_mode());
  EXPECT_TRUE(scene->surrogate.source.empty());
  EXPECT_EQ(scene->loop.imaging.model.min_span_s, 5.0) << "a model spans the scene's breath";
}

TEST(SceneImaging, TheModeAlone) {
  auto scene = parse("tracking:\n  imaging: model\nsurrogate: {source: sim}\n");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_TRUE(scene->loop.imaging.model_mode());
}

TEST(SceneImaging, AModelWithASimulatedMarker) {
  auto scene = parse(R"(tracking:
  imaging:
    mode: model
    xray_hz: 0.5
    stale_s: 4
    model: {order: quadratic, hysteresis: false, window: 30, min_pairs: 10, tolerance_mm: 2}
    technique: {kvp: 100, mas: 5}
surrogate:
  source: sim
  rate_hz: 30
  stale_ms: 200
  jump_mm: 4
  freeze_s: 1
  sim: {amplitude_mm: 12, lead_s: 0.3, drift_mm_per_min: 0.6, noise_sd_mm: 0.2}
)");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  const ImagingSpec& i = scene->loop.imaging;
  EXPECT_TRUE(i.model_mode());
  EXPECT_EQ(i.xray_hz, 0.5);
  EXPECT_EQ(i.stale_s, 4);
  EXPECT_EQ(i.model.order, CorrelationModelSpec::Order::kQuadratic);
  EXPECT_FALSE(i.model.hysteresis);
  EXPECT_EQ(i.model.window, 30);
  EXPECT_EQ(i.model.min_pairs, 10);
  EXPECT_EQ(i.model.tolerance_mm, 2);
  EXPECT_EQ(i.surrogate.rate_hz, 30);
  EXPECT_EQ(i.surrogate.stale_ms, 200);
  EXPECT_EQ(i.surrogate.jump, 4);
  EXPECT_EQ(i.surrogate.freeze_s, 1);
  EXPECT_EQ(scene->technique.kvp, 100);
  EXPECT_EQ(scene->technique.mas, 5);
  EXPECT_EQ(scene->surrogate.source, "sim");
  EXPECT_EQ(scene->surrogate.sim.amplitude, 12);
  EXPECT_EQ(scene->surrogate.sim.period_s, 5) << "the marker breathes with the patient";
  EXPECT_EQ(scene->surrogate.sim.sample_rate_hz, 30);
  EXPECT_NEAR(scene->surrogate.sim.drift_per_s, 0.01, 1e-12);
}

TEST(SceneImaging, RefusesWhatMakesNoSense) {
  const struct {
    const char* text;
    const char* says;
  } cases[] = {
      {"tracking:\n  imaging: {mode: model}\n", "needs a `surrogate` section"},
      {"tracking:\n  imaging: {mode: sometimes}\n", "tracking.imaging.mode"},
      {"tracking:\n  imaging: {xray_hz: 0}\n", "tracking.imaging.xray_hz"},
      {"tracking:\n  imaging: {xray_hz: .nan}\n", "finite"},
      {"tracking:\n  imaging: {xray_hz: 1e12}\n", "tracking.imaging.xray_hz"},
      {"tracking:\n  imaging: {mode: model, xray_hz: 20}\nsurrogate: {source: sim}\n",
       "above the loop's rate"},
      {"tracking:\n  imaging: {mode: model, xray_hz: 12}\nsurrogate: {source: sim}\nloop: {period_ms: 50, "
       "registration_budget_ms: 20, acquire_timeout_ms: 20}\n",
       "cannot span"},
      {"tracking:\n  imaging: {model: {min_pairs: 2}}\n", "min_pairs"},
      {"tracking:\n  imaging: {mode: model, xray_hz: 0.25}\nsurrogate: {source: sim}\n", "stale_s"},
      {"tracking:\n  imaging: sometimes\n", "tracking.imaging"},
      {"tracking:\n  imaging: {model: {order: cubic}}\n", "order"},
      {"tracking:\n  imaging: {technique: {kvp: -1}}\n", "kvp"},
      {"tracking:\n  imaging: {typo: 1}\n", "typo"},
      {"surrogate: {rate_hz: 60}\n", "needs 'source'"},
      {"surrogate: {source: radar}\n", "surrogate.source"},
      {"surrogate: {source: igtl, igtl: {port: 0}}\n", "surrogate.igtl.port"},
      {"surrogate: {source: igtl, igtl: {port: 70000}}\n", "surrogate.igtl.port"},
      {"surrogate: {source: igtl, igtl: {axis: [0, 0, 0]}}\n", "surrogate.igtl.axis"},
      {"surrogate: {source: igtl, igtl: {hostname: x}}\n", "hostname"},
      {"surrogate: {source: sim, igtl: {port: 1}}\n", "surrogate.igtl is for"},
      {"surrogate: {source: sim, rate_hz: 10, stale_ms: 100}\n", "two readings"},
      {"surrogate: {source: sim, sim: {amplitude_mm: 0}}\n", "amplitude_mm"},
  };
  for (const auto& c : cases) {
    auto scene = parse(c.text);
    ASSERT_FALSE(scene.ok()) << c.text;
    EXPECT_NE(scene.status().message().find(c.says), std::string::npos) << c.text << scene.status().message();
  }
}

TEST(SceneImaging, ReadsTheTrackersAddress) {
  auto scene = parse(
      "surrogate:\n  source: igtl\n  igtl: {host: tracker.local, port: 18945, device: ChestMarker, axis: [0, "
      "1, 0]}\n"
      "  sim: {amplitude_mm: 6}\n");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->surrogate.source, "igtl");
  EXPECT_EQ(scene->surrogate.igtl_host, "tracker.local");
  EXPECT_EQ(scene->surrogate.igtl_port, 18945);
  EXPECT_EQ(scene->surrogate.igtl_device, "ChestMarker");
  EXPECT_EQ(scene->surrogate.igtl_axis, Eigen::Vector3d::UnitY());
  EXPECT_EQ(scene->surrogate.sim.amplitude, 6) << "the marker lftrack sim serves behind the protocol";
}

// What a session checks of the surrogate before it loads anything (check_session_surrogate): a watch
// no slower than the gate's frame age, the simulated marker only in simulation, an OpenIGTLink
// tracker only on the real clock.
TEST(SceneImaging, TheSessionRefusesASurrogateItCannotFollowBeforeLoading) {
  const std::string model = "tracking:\n  imaging: {mode: model}\n";
  LoopSessionOptions sim;
  sim.simulator = sim_devices::room_simulator();
  auto ok = parse(model + "surrogate: {source: sim}\n");
  ASSERT_TRUE(ok.ok()) << ok.status().message();
  EXPECT_TRUE(check_session_surrogate(*ok, sim).ok());
  auto slow = parse(model + "surrogate: {source: sim, stale_ms: 400}\n");
  ASSERT_TRUE(slow.ok()) << slow.status().message();
  const Status slow_watch = check_session_surrogate(*slow, sim);
  EXPECT_FALSE(slow_watch.ok());
  EXPECT_NE(slow_watch.message().find("safety.max_frame_age_ms"), std::string::npos) << slow_watch.message();
  LoopSessionOptions room;
  room.simulator = sim_devices::room_simulator();
  room.devices = SessionDevices::kScene;
  const Status sim_in_room = check_session_surrogate(*ok, room);
  EXPECT_FALSE(sim_in_room.ok());
  EXPECT_NE(sim_in_room.message().find("surrogate.source igtl"), std::string::npos) << sim_in_room.message();
  auto igtl = parse(model + "surrogate: {source: igtl}\n");
  ASSERT_TRUE(igtl.ok()) << igtl.status().message();
  EXPECT_TRUE(check_session_surrogate(*igtl, sim).ok()) << "lftrack sim on the real clock serves the twin";
  EXPECT_TRUE(check_session_surrogate(*igtl, room).ok());
  LoopSessionOptions fast;
  fast.simulator = sim_devices::room_simulator();
  fast.simulated_clock = true;
  const Status igtl_fast = check_session_surrogate(*igtl, fast);
  EXPECT_FALSE(igtl_fast.ok());
  EXPECT_NE(igtl_fast.message().find("--fast"), std::string::npos) << igtl_fast.message();
  LoopSessionOptions replay = fast;
  replay.replay_sequence = "archive";
  EXPECT_TRUE(check_session_surrogate(*igtl, replay).ok()) << "a replay registers every archived pair";
}

TEST(SceneImaging, TheDoseModelsNumbers) {
  ImagingTechniqueSpec t;
  t.kvp = 100;
  t.mas = 1;
  EXPECT_NEAR(skin_entrance_dose_mGy(t, 1000), kOutputAt100kV * kBackscatter, 1e-12);
  EXPECT_NEAR(skin_entrance_dose_mGy(t, 500), 4 * kOutputAt100kV * kBackscatter, 1e-12) << "inverse square";
  t.kvp = 120;
  t.mas = 2;
  EXPECT_NEAR(skin_entrance_dose_mGy(t, 1000), 2 * 1.44 * kOutputAt100kV * kBackscatter, 1e-12)
      << "kV squared, mAs";
  EXPECT_TRUE(std::isfinite(skin_entrance_dose_mGy(t, 0)))
      << "a source at the skin is no geometry, not infinity";
}

TEST(SimSurrogateSource, ReadingsAtItsRateOnTheRoomsClockWithFaults) {
  sim::SimulatedRoomSpec room_spec;
  sim::SimulatedRoom room(room_spec);
  sim_spec::BreathingSurrogateSpec spec;
  spec.sample_rate_hz = 50;
  spec.noise_sd = 0;
  SimSurrogateFaults faults;
  faults.freeze_from_s = 1.0;
  faults.stop_from_s = 2.0;
  SimSurrogateSource source(spec, &room, faults);
  drivers::SurrogateReading out[8];
  EXPECT_EQ(source.read(5'000'000'000, out, 8), 0) << "nothing before the room's clock starts";
  room.advance_to_ns(5'000'000'000);
  EXPECT_EQ(source.read(5'000'000'000, out, 8), 1);
  EXPECT_EQ(out[0].t_ns, 5'000'000'000);
  EXPECT_EQ(source.read(5'100'000'000, out, 8), 5) << "20 ms apart, up to and with 100 ms";
  EXPECT_EQ(out[4].t_ns, 5'100'000'000);
  EXPECT_EQ(source.read(5'100'000'000, out, 8), 0) << "each reading is given once";
  EXPECT_EQ(source.read(5'900'000'000, out, 8), 8) << "the newest eight of forty";
  EXPECT_EQ(out[7].t_ns, 5'900'000'000);
  sim::BreathingSurrogate exact(spec);
  EXPECT_NEAR(out[7].amplitude, exact.exact(0.9), 1e-12);
  // Frozen from 1 s: every reading the one at 1 s.
  EXPECT_EQ(source.read(6'500'000'000, out, 8), 8);
  for (const drivers::SurrogateReading& r : out) EXPECT_EQ(r.amplitude, exact.exact(1.0));
  // Stopped from 2 s: no readings.
  EXPECT_EQ(source.read(6'980'000'000, out, 8), 8);
  EXPECT_EQ(source.read(8'000'000'000, out, 8), 0);
}

}  // namespace
}  // namespace lftrack::session
