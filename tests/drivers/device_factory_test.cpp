// The device factory (device_factory.hpp): each spec builds its kind, unopened; a spec that cannot
// work is refused with a message that names the device, before anything is opened.

#include "lftrack/drivers/device_factory.hpp"

#include <gtest/gtest.h>
#include <sys/socket.h>
#include <unistd.h>

#include <functional>
#include <string>

#include "lftrack/drivers/frame_files.hpp"
#include "lftrack/drivers/frame_sequence.hpp"
#include "test_data.hpp"

namespace lftrack::drivers {
namespace {

V4l2SourceSpec two_v4l2_detectors() {
  V4l2SourceSpec spec;
  for (const char* device : {"/dev/v4l/by-path/panel-a", "/dev/v4l/by-path/panel-b"}) {
    V4l2DetectorOptions d;
    d.device = device;
    d.rows = 8;
    d.cols = 12;
    spec.detectors.push_back(d);
  }
  return spec;
}

TEST(DeviceFactory, EachSpecBuildsItsKindUnopened) {
  auto v4l2 = make_frame_source(two_v4l2_detectors());
  ASSERT_TRUE(v4l2.ok()) << v4l2.status().message();
  EXPECT_NE(dynamic_cast<V4l2FrameSource*>(v4l2->get()), nullptr);

  auto modbus = make_actuator(ModbusActuatorSpec{});
  ASSERT_TRUE(modbus.ok()) << modbus.status().message();
  EXPECT_NE(dynamic_cast<ModbusCouch*>(modbus->get()), nullptr);

  int link[2];
  ASSERT_EQ(::socketpair(AF_UNIX, SOCK_SEQPACKET, 0, link), 0);
  auto can = make_actuator(CanActuatorSpec{CanRobotOptions{}, link[0]});
  ASSERT_TRUE(can.ok()) << can.status().message();
  EXPECT_NE(dynamic_cast<CanRobot*>(can->get()), nullptr);
  ::close(link[1]);

  EXPECT_STREQ(kind_name(FrameSourceSpec{V4l2SourceSpec{}}), "v4l2");
  EXPECT_STREQ(kind_name(FrameSourceSpec{ReplaySourceSpec{}}), "replay");
  EXPECT_STREQ(kind_name(ActuatorSpec{ModbusActuatorSpec{}}), "modbus");
  EXPECT_STREQ(kind_name(ActuatorSpec{CanActuatorSpec{}}), "can");
  EXPECT_STREQ(kind_name(ActuatorSpec{RecordedActuatorSpec{}}), "recorded");
}

TEST(DeviceFactory, AReplayedSequenceAndItsRecordedCouch) {
  test::TempDir dir;
  SequenceIndexWriter writer;
  ASSERT_TRUE(writer.open(dir.path(), true).ok());
  for (int v = 0; v < 2; ++v) {
    tracking::Image<std::uint16_t> frame(8, 12, std::uint16_t(100 + v));
    const std::string name = v == 0 ? "frames/0-A.tif" : "frames/0-B.tif";
    ASSERT_TRUE(write_frame_file((dir.path() / name).c_str(), frame.view()).ok());
    ASSERT_TRUE(writer.append(0, v == 0 ? "A" : "B", 1, 1'000'000 + v, name.c_str()).ok());
  }
  const double travel[6] = {1, 0, 0, 0, 0, 0};
  ASSERT_TRUE(writer.append_actuator(0, travel).ok());
  ASSERT_TRUE(writer.close().ok());

  ReplaySourceSpec spec;
  spec.sequence = dir.path();
  spec.detectors = {{"A", 8, 12}, {"B", 8, 12}};
  auto frames = make_frame_source(spec);
  ASSERT_TRUE(frames.ok()) << frames.status().message();
  const auto* replay = dynamic_cast<const ReplayFrameSource*>(frames->get());
  ASSERT_NE(replay, nullptr);
  auto couch = make_actuator(RecordedActuatorSpec{replay});
  EXPECT_TRUE(couch.ok()) << couch.status().message();

  spec.sequence = dir.path() / "no-such-sequence";
  auto missing = make_frame_source(spec);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("no-such-sequence"), std::string::npos) << missing.status().message();
}

struct BadSpec {
  const char* name;
  std::function<Status()> make;
  const char* message;
};

void PrintTo(const BadSpec& c, std::ostream* os) {
  *os << c.name;
}

Status frame_source_of(V4l2SourceSpec spec) {
  return make_frame_source(std::move(spec)).status();
}

Status actuator_of(ActuatorSpec spec) {
  return make_actuator(std::move(spec)).status();
}

const BadSpec kBadSpecs[] = {
    {"NoDetectors", [] { return frame_source_of(V4l2SourceSpec{}); }, "no detectors"},
    {"NoDevicePath",
     [] {
       V4l2SourceSpec s = two_v4l2_detectors();
       s.detectors[1].device.clear();
       return frame_source_of(s);
     },
     "v4l2 detector 2: no device path"},
    {"ZeroRows",
     [] {
       V4l2SourceSpec s = two_v4l2_detectors();
       s.detectors[0].rows = 0;
       return frame_source_of(s);
     },
     "panel-a): rows and cols"},
    {"HugeCols",
     [] {
       V4l2SourceSpec s = two_v4l2_detectors();
       s.detectors[0].cols = 1 << 30;
       return frame_source_of(s);
     },
     "rows and cols must be 1 to 16384"},
    {"OneBuffer",
     [] {
       V4l2SourceSpec s = two_v4l2_detectors();
       s.detectors[0].buffers = 1;
       return frame_source_of(s);
     },
     "buffers must be 2 to 32"},
    {"NanSkew",
     [] {
       V4l2SourceSpec s = two_v4l2_detectors();
       s.max_skew_ms = std::numeric_limits<double>::quiet_NaN();
       return frame_source_of(s);
     },
     "max_skew_ms"},
    {"ReplayWithoutDetectors", [] { return make_frame_source(ReplaySourceSpec{}).status(); }, "no detectors"},
    {"ModbusWithoutHost",
     [] {
       ModbusActuatorSpec m;
       m.options.host.clear();
       return actuator_of(m);
     },
     "TCP needs a host"},
    {"ModbusPortZero",
     [] {
       ModbusActuatorSpec m;
       m.options.port = 0;
       return actuator_of(m);
     },
     "port from 1 to 65535"},
    {"ModbusRtuWithoutDevice",
     [] {
       ModbusActuatorSpec m;
       m.options.transport = ModbusCouchOptions::Transport::kRtu;
       return actuator_of(m);
     },
     "RTU needs a serial device"},
    {"ModbusUnit300",
     [] {
       ModbusActuatorSpec m;
       m.options.unit_id = 300;
       return actuator_of(m);
     },
     "unit id"},
    {"ModbusInfiniteTimeout",
     [] {
       ModbusActuatorSpec m;
       m.options.response_timeout_s = std::numeric_limits<double>::infinity();
       return actuator_of(m);
     },
     "response timeout"},
    {"CanNode0",
     [] {
       CanActuatorSpec c;
       c.options.node_id = 0;
       return actuator_of(c);
     },
     "node id must be 1 to 15"},
    {"CanWithoutInterfaceOrLink",
     [] {
       CanActuatorSpec c;
       c.options.interface.clear();
       return actuator_of(c);
     },
     "no interface"},
    {"RecordedWithoutSequence", [] { return actuator_of(RecordedActuatorSpec{}); }, "needs the replayed sequence"},
};

class DeviceFactoryRefuses : public ::testing::TestWithParam<BadSpec> {};

TEST_P(DeviceFactoryRefuses, WithAMessageThatNamesTheDevice) {
  const Status s = GetParam().make();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find(GetParam().message), std::string::npos) << s.message();
}

INSTANTIATE_TEST_SUITE_P(Specs, DeviceFactoryRefuses, ::testing::ValuesIn(kBadSpecs),
                         [](const auto& p) { return std::string(p.param.name); });

}  // namespace
}  // namespace lftrack::drivers
