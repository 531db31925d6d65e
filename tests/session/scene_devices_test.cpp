// The scene's devices: detectors[].frames with their settings, actuator modbus and can, and the
// drivers' specs and words made from them (scene_devices.hpp). Every refusal names the file and
// line.

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <variant>

#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

// The built-in scene with both detectors' `frames: sim` replaced by `frames`, and its actuator
// section's first line `type: virtual` replaced by `actuator` (default none: the simulator's
// couch needs simulated detectors).
std::string scene_with(const std::string& frames, const std::string& actuator = "type: none") {
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  for (std::size_t at = text.find("frames: sim"); at != std::string::npos; at = text.find("frames: sim", at + 1)) {
    text.replace(at, 11, "frames: " + frames);
    at += frames.size();
  }
  text.replace(text.find("type: virtual"), 13, actuator);
  return text;
}

Result<Scene> parse(const std::string& text) {
  return parse_scene(text, "room.yaml", "/srv/room");
}

void expect_scene_refused(const std::string& text, const std::string& expect) {
  auto s = parse(text);
  ASSERT_FALSE(s.ok()) << "accepted:\n" << text;
  EXPECT_NE(s.status().message().find(expect), std::string::npos) << s.status().message();
  EXPECT_NE(s.status().message().find("room.yaml:"), std::string::npos) << "with the line: " << s.status().message();
}

TEST(SceneDevices, V4l2DetectorsBecomeTheFactorysSpec) {
  std::string text = scene_with("{type: v4l2, device: /dev/v4l/by-path/DEV, buffers: 6, trigger_control: 10094849}");
  const std::size_t second = text.find("/dev/v4l/by-path/DEV", text.find("/dev/v4l/by-path/DEV") + 1);
  text.replace(second, 20, "/dev/v4l/by-path/DEV2");
  text.replace(text.find("/dev/v4l/by-path/DEV,"), 21, "/dev/v4l/by-path/DEV1,");
  auto scene = parse(text);
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->detectors[0].frames.kind, "v4l2");
  EXPECT_EQ(scene->detectors[0].frames.buffers, 6);
  EXPECT_EQ(scene->detectors[0].frames.trigger_control_id, 10094849u);
  EXPECT_EQ(describe_frames(scene->detectors[1].frames), "v4l2 /dev/v4l/by-path/DEV2");
  auto spec = device_frame_source_spec(*scene);
  ASSERT_TRUE(spec.ok()) << spec.status().message();
  ASSERT_TRUE(std::holds_alternative<drivers::V4l2SourceSpec>(*spec));
  const auto& v = std::get<drivers::V4l2SourceSpec>(*spec);
  ASSERT_EQ(v.detectors.size(), 2u);
  EXPECT_EQ(v.detectors[0].device, "/dev/v4l/by-path/DEV1");
  EXPECT_EQ(v.detectors[1].rows, 512);
  EXPECT_EQ(drivers::kind_name(*spec), std::string("v4l2"));
  // What a scene writes back (calibrate views keeps the detectors' sources) parses again.
  EXPECT_EQ(frames_yaml(scene->detectors[0].frames),
            "{type: v4l2, device: \"/dev/v4l/by-path/DEV1\", buffers: 6, trigger_control: 10094849, trigger_value: 1}");
}

TEST(SceneDevices, ReplayAndGigeResolveTheirSettings) {
  auto replay = parse(scene_with("{type: replay, sequence: archive/day1}"));
  ASSERT_TRUE(replay.ok()) << replay.status().message();
  EXPECT_EQ(replay->detectors[1].frames.sequence, "/srv/room/archive/day1") << "relative to the scene's folder";
  auto spec = device_frame_source_spec(*replay);
  ASSERT_TRUE(spec.ok());
  EXPECT_EQ(std::get<drivers::ReplaySourceSpec>(*spec).sequence, "/srv/room/archive/day1");
  std::string gige = scene_with("{type: gige, camera: 10.0.0.5, packet_timeout_ms: 40}");
  gige.replace(gige.find("10.0.0.5", gige.find("10.0.0.5") + 1), 8, "10.0.0.6");
  auto g = parse(gige);
  ASSERT_TRUE(g.ok()) << g.status().message();
  EXPECT_EQ(g->detectors[0].frames.device, "10.0.0.5");
  EXPECT_EQ(g->detectors[1].frames.device, "10.0.0.6");
  EXPECT_DOUBLE_EQ(g->detectors[0].frames.packet_timeout_ms, 40);
  EXPECT_FALSE(g->detectors[0].frames.exposure_by_arrival) << "the camera's clock by default";
  auto gige_spec = device_frame_source_spec(*g);
  ASSERT_TRUE(gige_spec.ok());
  EXPECT_EQ(std::get<drivers::GigeSourceSpec>(*gige_spec).detectors[0].exposure_clock,
            drivers::ExposureClock::kDevice);
  // exposure_clock: arrival reaches the driver, and is written back.
  std::string by_arrival = scene_with("{type: gige, camera: 10.0.0.5, exposure_clock: arrival}");
  by_arrival.replace(by_arrival.find("10.0.0.5", by_arrival.find("10.0.0.5") + 1), 8, "10.0.0.6");
  auto a = parse(by_arrival);
  ASSERT_TRUE(a.ok()) << a.status().message();
  EXPECT_TRUE(a->detectors[1].frames.exposure_by_arrival);
  auto arrival_spec = device_frame_source_spec(*a);
  ASSERT_TRUE(arrival_spec.ok());
  EXPECT_EQ(std::get<drivers::GigeSourceSpec>(*arrival_spec).detectors[1].exposure_clock,
            drivers::ExposureClock::kArrival);
  EXPECT_EQ(frames_yaml(a->detectors[0].frames),
            "{type: gige, camera: \"10.0.0.5\", buffers: 4, packet_timeout_ms: 20, exposure_clock: arrival}");
}

// The device id a GigE camera must answer with (the start-up checks compare it); written back.
TEST(SceneDevices, AGigeCameraCanNameTheIdItMustAnswerWith) {
  std::string gige = scene_with("{type: gige, camera: 10.0.0.5, id: PANEL-0001}");
  gige.replace(gige.find("10.0.0.5", gige.find("10.0.0.5") + 1), 8, "10.0.0.6");
  auto g = parse(gige);
  ASSERT_TRUE(g.ok()) << g.status().message();
  EXPECT_EQ(g->detectors[0].frames.id, "PANEL-0001");
  EXPECT_EQ(frames_yaml(g->detectors[0].frames),
            "{type: gige, camera: \"10.0.0.5\", buffers: 4, packet_timeout_ms: 20, id: \"PANEL-0001\"}");
  EXPECT_EQ(served_twin_id("A"), "LFTRACK-A") << "how lftrack serve detectors names its cameras";
  // Issue 50 probe: ids cut to 15 characters made "lateral-left" and "lateral-right" one id, so a
  // swap of their cameras passed the identity check.
  EXPECT_NE(served_twin_id("lateral-left"), served_twin_id("lateral-right"));
  EXPECT_EQ(served_twin_id("lateral-left").size(), 15u);
  EXPECT_EQ(served_twin_id("lateral-left"), served_twin_id("lateral-left")) << "the same name, the same id";
  EXPECT_EQ(served_twin_id("lateral").size(), 15u);
  EXPECT_EQ(served_twin_id("lateral"), "LFTRACK-lateral");
  expect_scene_refused(scene_with("{type: v4l2, device: /dev/video0, id: X}"), "unknown key 'id'");
}

TEST(SceneDevices, BadFrameSourcesAreRefusedWithTheLine) {
  expect_scene_refused(scene_with("v4l2"), "v4l2 needs its device");
  expect_scene_refused(scene_with("gige"), "gige needs its device");
  expect_scene_refused(scene_with("{type: v4l2}"), "needs 'device'");
  expect_scene_refused(scene_with("{type: v4l2, device: video0}"), "absolute path");
  expect_scene_refused(scene_with("{type: v4l2, device: /dev/video0, buffers: 1}"), "buffers must be in 2..32");
  expect_scene_refused(scene_with("{type: v4l2, device: /dev/video0, buffers: 1e12}"), "buffers");
  expect_scene_refused(scene_with("{type: v4l2, device: /dev/video0, speed: 3}"), "unknown key 'speed'");
  expect_scene_refused(scene_with("{type: gige, camera: x, packet_timeout_ms: .nan}"), "must be finite");
  expect_scene_refused(scene_with("{type: gige, camera: x, packet_timeout_ms: -1}"), "must be positive");
  expect_scene_refused(scene_with("{type: gige, camera: x, exposure_clock: ptp}"), "exposure_clock");
  expect_scene_refused(scene_with("{type: gige, camera: x, exposure_clock: [device]}"), "exposure_clock");
  expect_scene_refused(scene_with("{type: replay}"), "needs 'sequence'");
  expect_scene_refused(scene_with("{type: firewire}"), "firewire");
  expect_scene_refused(scene_with("[sim]"), "a kind (sim, replay) or a mapping");
  expect_scene_refused(scene_with("{type: v4l2, device: /dev/video0}"), "two detectors name the same device");
  std::string mixed = *builtin_scene_text(kBuiltinPhantom);
  mixed.replace(mixed.find("frames: sim"), 11, "frames: {type: v4l2, device: /dev/video0}");
  expect_scene_refused(mixed, "a pair comes from one source");
  std::string two_sequences = scene_with("{type: replay, sequence: a}");
  two_sequences.replace(two_sequences.rfind("sequence: a"), 11, "sequence: b");
  expect_scene_refused(two_sequences, "two sequences");
  // The simulator's couch moves a simulated patient only.
  std::string virtual_couch = scene_with("{type: v4l2, device: /dev/video0}", "type: virtual");
  virtual_couch.replace(virtual_couch.rfind("/dev/video0"), 11, "/dev/video1");
  expect_scene_refused(virtual_couch, "actuator.type virtual is the simulator's couch");
}

TEST(SceneDevices, ModbusAndCanActuatorsParse) {
  auto tcp = parse(scene_with("sim", "type: modbus\n  modbus: {tcp: {host: couch.room, port: 1502}, unit_id: 7, "
                                     "response_timeout_ms: 15}"));
  ASSERT_TRUE(tcp.ok()) << tcp.status().message();
  EXPECT_EQ(tcp->actuator.type, "modbus");
  EXPECT_EQ(tcp->actuator.modbus.host, "couch.room");
  EXPECT_EQ(tcp->actuator.modbus.port, 1502);
  EXPECT_EQ(tcp->actuator.modbus.unit_id, 7);
  EXPECT_DOUBLE_EQ(tcp->actuator.modbus.response_timeout_s, 0.015);
  EXPECT_EQ(describe_actuator(tcp->actuator), "modbus tcp couch.room:1502 unit 7");
  auto spec = device_actuator_spec(*tcp);
  ASSERT_TRUE(spec.ok());
  EXPECT_EQ(drivers::kind_name(*spec), std::string("modbus"));
  auto rtu = parse(scene_with("sim", "type: modbus\n  modbus: {rtu: {device: /dev/ttyUSB0, baud: 38400, parity: none, "
                                     "stop_bits: 2}}"));
  ASSERT_TRUE(rtu.ok()) << rtu.status().message();
  EXPECT_EQ(rtu->actuator.modbus.transport, drivers::ModbusCouchOptions::Transport::kRtu);
  EXPECT_EQ(rtu->actuator.modbus.parity, 'N');
  EXPECT_EQ(rtu->actuator.modbus.stop_bits, 2);
  auto bridge = parse(scene_with("sim", "type: can\n  can: {bridge: run/robot.sock, node_id: 3}"));
  ASSERT_TRUE(bridge.ok()) << bridge.status().message();
  EXPECT_EQ(bridge->actuator.can.bridge_path, "/srv/room/run/robot.sock");
  EXPECT_EQ(bridge->actuator.can.node_id, 3);
  EXPECT_EQ(describe_actuator(bridge->actuator), "can bridge /srv/room/run/robot.sock node 3");
  auto can0 = parse(scene_with("sim", "type: can\n  can: {interface: can0}"));
  ASSERT_TRUE(can0.ok()) << can0.status().message();
  EXPECT_EQ(can0->actuator.can.interface, "can0");
  EXPECT_TRUE(can0->actuator.can.bridge_path.empty());
}

TEST(SceneDevices, BadActuatorsAreRefusedWithTheLine) {
  expect_scene_refused(scene_with("sim", "type: modbus"), "needs actuator.modbus");
  expect_scene_refused(scene_with("sim", "type: modbus\n  modbus: {}"), "needs its link");
  expect_scene_refused(scene_with("sim", "type: modbus\n  modbus: {tcp: {host: a, port: 0}}"), "port must be in 1..65535");
  expect_scene_refused(scene_with("sim", "type: modbus\n  modbus: {tcp: {host: a, port: 70000}}"), "1..65535");
  expect_scene_refused(scene_with("sim", "type: modbus\n  modbus: {tcp: {host: a}, rtu: {device: b}}"), "both tcp and rtu");
  expect_scene_refused(scene_with("sim", "type: modbus\n  modbus: {rtu: {device: /dev/ttyS0, baud: 12345}}"), "standard rate");
  expect_scene_refused(scene_with("sim", "type: modbus\n  modbus: {tcp: {host: a}, unit_id: 300}"), "unit_id must be in 1..247");
  expect_scene_refused(scene_with("sim", "type: modbus\n  modbus: {tcp: {host: a}, unit_id: 0}"), "unit_id must be in 1..247");
  // A key written twice: YAML would keep the first; refused with the second's line.
  std::string twice = scene_with("sim");
  twice.replace(twice.find("  max_step_mm: 2\n"), 16, "  max_step_mm: 20\n  max_step_mm: 2\n");
  expect_scene_refused(twice, "'max_step_mm' appears twice in safety");
  expect_scene_refused(scene_with("sim", "type: modbus\n  modbus: {tcp: {host: a}, response_timeout_ms: .inf}"), "finite");
  expect_scene_refused(scene_with("sim", "type: modbus\n  modbus: {tcp: {host: a}, response_timeout_ms: 0}"), "positive");
  expect_scene_refused(scene_with("sim", "type: can"), "needs actuator.can");
  expect_scene_refused(scene_with("sim", "type: can\n  can: {node_id: 2}"), "an interface (e.g. can0) or a bridge");
  expect_scene_refused(scene_with("sim", "type: can\n  can: {interface: can0, bridge: x}"), "both interface and bridge");
  expect_scene_refused(scene_with("sim", "type: can\n  can: {interface: can0, node_id: 16}"), "node_id must be in 1..15");
  expect_scene_refused(scene_with("sim", "type: can\n  can: {bridge: " + std::string(120, 'x') + "}"), "at most 107 bytes");
  expect_scene_refused(scene_with("sim", "type: virtual\n  can: {interface: can0}"), "actuator.can is for actuator.type can");
}

TEST(SceneDevices, ADetectorCalibrationMustExist) {
  test::TempDir dir;
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  text.replace(text.find("frames: sim"), 11, "frames: sim\n    calibration: detector-A.tif");
  auto missing = parse_scene(text, "room.yaml", dir.path());
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("no detector calibration file"), std::string::npos);
  EXPECT_NE(missing.status().message().find("lftrack calibrate detector"), std::string::npos);
  std::ofstream(dir.path() / "detector-A.tif") << "x";
  auto found = parse_scene(text, "room.yaml", dir.path());
  ASSERT_TRUE(found.ok()) << found.status().message();
  EXPECT_EQ(found->detectors[0].calibration_file, (dir.path() / "detector-A.tif").string());
  EXPECT_TRUE(found->detectors[1].calibration_file.empty());
}

// `frames` and `actuator` as scene_with, and sim.couch_link named.
std::string with_couch_link(const std::string& frames, const std::string& actuator) {
  std::string text = scene_with(frames, actuator);
  text.replace(text.find("detector_blur_px: 0.5"), 21, "detector_blur_px: 0.5\n  couch_link: hil/room.link");
  return text;
}

TEST(SceneDevices, SimulatedDetectorsCanNameACouchLink) {
  for (const char* served : {"type: modbus\n  modbus: {tcp: {host: 127.0.0.1}}", "type: can\n  can: {interface: can0}"}) {
    auto scene = parse(with_couch_link("sim", served));
    ASSERT_TRUE(scene.ok()) << scene.status().message();
    EXPECT_EQ(scene->sim.couch_link, "/srv/room/hil/room.link");
  }
}

// A room link that nothing would read or write is a mistake in the scene, not a quiet no-op
// (issue 50): only simulated detectors read it, and only a served couch or robot writes it.
TEST(SceneDevices, ACouchLinkNoDeviceCanUseIsRefusedWithTheLine) {
  expect_scene_refused(with_couch_link("sim", "type: none"), "sim.couch_link");
  expect_scene_refused(with_couch_link("sim", "type: none"), "actuator.type none");
  expect_scene_refused(with_couch_link("sim", "type: virtual"), "actuator.type virtual");
  std::string gige = with_couch_link("{type: gige, camera: 10.0.0.5}", "type: modbus\n  modbus: {tcp: {host: a}}");
  gige.replace(gige.find("10.0.0.5", gige.find("10.0.0.5") + 1), 8, "10.0.0.6");
  expect_scene_refused(gige, "simulated detectors");
  auto line = parse(with_couch_link("sim", "type: none"));
  ASSERT_FALSE(line.ok());
  const std::string text = with_couch_link("sim", "type: none");
  const int couch_link_line = int(std::count(text.begin(), text.begin() + long(text.find("couch_link")), '\n')) + 1;
  EXPECT_EQ(line.status().message().rfind("room.yaml:" + std::to_string(couch_link_line) + ":", 0), 0u)
      << "the couch_link's line: " << line.status().message();
}

// Frames from an archive show a patient who is no longer there: a real couch or robot corrected
// by them would move the patient in the room now for motion the archive shows (issue 50: `run`
// accepted it, drove the recorded read-backs instead, and said the couch had answered).
TEST(SceneDevices, ArchivedFramesWithARealCouchOrRobotAreRefused) {
  expect_scene_refused(scene_with("{type: replay, sequence: archive/day1}", "type: modbus\n  modbus: {tcp: {host: a}}"),
                 "archived frames cannot move a patient");
  expect_scene_refused(scene_with("replay", "type: can\n  can: {interface: can0}"), "archived frames cannot move a patient");
  EXPECT_TRUE(parse(scene_with("{type: replay, sequence: archive/day1}")).ok()) << "with no actuator: track and report";
}

}  // namespace
}  // namespace lftrack::session
