// GVCP as the fake GigE cameras check it (sim/gvcp.hpp): every datagram sorted into answered,
// refused with its status, or dropped, in process; then a fake camera (sim/gige_fake_detector.hpp)
// on loopback fed malformed datagrams of many shapes by a raw UDP client: it drops or refuses
// each, still answers a well-formed read, and the GigE driver still opens it and takes frames.

#include "lftrack/sim/gvcp.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <vector>

#include "gige_host_lock.hpp"
#include "gvcp_probe.hpp"
#include "lftrack/drivers/gige_detector.hpp"
#include "lftrack/sim/gige_fake_detector.hpp"
#include "protocol_test_support.hpp"

namespace lftrack {
namespace {

namespace gvcp = sim::gvcp;
using test::gvcp_datagram;
using namespace std::chrono_literals;

constexpr gvcp::MemoryMap kMap{0x10000 + 0x2000, 0x10000};  // registers, then a read-only description

gvcp::Checked check(const std::vector<std::uint8_t>& d) {
  return gvcp::check_command(d.data(), d.size(), kMap);
}

TEST(Gvcp, DropsWhatIsNotAWellFormedCommand) {
  const std::vector<std::vector<std::uint8_t>> dropped = {
      {},
      {0x42},
      {0x42, 0x01, 0x00, 0x80, 0x00, 0x04, 0x00},
      gvcp_datagram(0x0080, 0xFFFC, {0x1F0}),      // length past the datagram
      gvcp_datagram(0x0080, 6, {0x1F0, 0}),        // length not a multiple of 4
      gvcp_datagram(0x0080, 0, {}),                // no address
      gvcp_datagram(0x0082, 4, {0x1F0}),           // half a pair
      gvcp_datagram(0x0084, 4, {0x0000}),          // no count
      gvcp_datagram(0x0086, 4, {0x0000}),          // no data
      gvcp_datagram(0x0086, 0xFFF0, {0x0000, 1}),  // length past the datagram
      gvcp_datagram(0x0040, 12, {0, 0, 0}),        // packet resend: not answered
  };
  for (std::size_t i = 0; i < dropped.size(); ++i) {
    const gvcp::Checked c = check(dropped[i]);
    EXPECT_EQ(c.verdict, gvcp::Verdict::kDrop) << "datagram " << i << ": " << c.reason;
    EXPECT_STRNE(c.reason, "") << i;
  }
  std::vector<std::uint8_t> acknowledge = gvcp_datagram(0x0080, 4, {0x1F0});
  acknowledge[0] = 0x00;
  EXPECT_EQ(check(acknowledge).verdict, gvcp::Verdict::kDrop) << "an acknowledge is not a command";
  const gvcp::Checked no_key = gvcp::check_command(nullptr, 0, kMap);
  EXPECT_EQ(no_key.verdict, gvcp::Verdict::kDrop);
}

TEST(Gvcp, RefusesWhatItCannotCarryOutWithTheStatusACameraGives) {
  struct Case {
    std::vector<std::uint8_t> datagram;
    gvcp::Status status;
  };
  const std::vector<Case> refused = {
      {gvcp_datagram(0x1234, 0, {}), gvcp::Status::kNotImplemented},
      {gvcp_datagram(0x0080, 4, {0xFFFFFFFC}), gvcp::Status::kInvalidAddress},
      {gvcp_datagram(0x0080, 8, {0x1F0, 0x12000}),
       gvcp::Status::kInvalidAddress},  // the second is past the map
      {gvcp_datagram(0x0080, 4, {0x1F1}), gvcp::Status::kBadAlignment},
      {gvcp_datagram(0x0080, 540, std::vector<std::uint32_t>(135, 0x1F0)), gvcp::Status::kInvalidParameter},
      {gvcp_datagram(0x0082, 8, {0xFFFFFFF0, 1}), gvcp::Status::kInvalidAddress},
      {gvcp_datagram(0x0082, 8, {0x10000, 1}), gvcp::Status::kWriteProtect},
      {gvcp_datagram(0x0082, 8, {0x1F2, 1}), gvcp::Status::kBadAlignment},
      {gvcp_datagram(0x0084, 8, {0x0000, 0}), gvcp::Status::kInvalidParameter},
      {gvcp_datagram(0x0084, 8, {0x0000, 0xFFFF}), gvcp::Status::kInvalidParameter},
      {gvcp_datagram(0x0084, 8, {0x0000, 538}), gvcp::Status::kInvalidParameter},
      {gvcp_datagram(0x0084, 8, {0xFFFFFF00, 512}), gvcp::Status::kInvalidAddress},
      {gvcp_datagram(0x0084, 8, {0xFFFFFFFC, 8}), gvcp::Status::kInvalidAddress},  // wraps past 2^32
      {gvcp_datagram(0x0084, 8, {0x11FFC, 8}), gvcp::Status::kInvalidAddress},     // runs past the map
      {gvcp_datagram(0x0086, 8, {0xFFFFFFFC, 1}), gvcp::Status::kInvalidAddress},
      {gvcp_datagram(0x0086, 8, {0x10000, 1}), gvcp::Status::kWriteProtect},
      {gvcp_datagram(0x0086, 12, {0xFFFC, 1, 2}), gvcp::Status::kWriteProtect},  // runs into the description
  };
  for (std::size_t i = 0; i < refused.size(); ++i) {
    const gvcp::Checked c = check(refused[i].datagram);
    EXPECT_EQ(c.verdict, gvcp::Verdict::kRefuse) << "case " << i << ": " << c.reason;
    EXPECT_EQ(c.status, refused[i].status) << "case " << i << ": " << c.reason;
    EXPECT_EQ(c.id, 0x4242) << "the error acknowledge answers the command's id";
  }
}

TEST(Gvcp, AnswersWhatLiesInsideTheMemoryMap) {
  gvcp::Checked c = check(gvcp_datagram(0x0002, 0, {}));
  EXPECT_EQ(c.verdict, gvcp::Verdict::kAnswer);
  EXPECT_TRUE(c.ack_required);
  c = check(gvcp_datagram(0x0080, 8, {0x1F0, 0x11FFC}));  // the last word of the map
  ASSERT_EQ(c.verdict, gvcp::Verdict::kAnswer) << c.reason;
  EXPECT_EQ(c.length, 8u);
  c = check(gvcp_datagram(0x0084, 8, {0x11E00, 512}));
  ASSERT_EQ(c.verdict, gvcp::Verdict::kAnswer) << c.reason;
  EXPECT_EQ(c.address, 0x11E00u);
  EXPECT_EQ(c.count, 512u);
  c = check(gvcp_datagram(0x0086, 12, {0xFFF8, 1, 2}));  // the last two writable words
  ASSERT_EQ(c.verdict, gvcp::Verdict::kAnswer) << c.reason;
  EXPECT_EQ(c.count, 8u);
  c = check(gvcp_datagram(0x0082, 16, {0xA00, 2, 0xD00, 5000}));
  ASSERT_EQ(c.verdict, gvcp::Verdict::kAnswer) << c.reason;
  // A datagram longer than its length field: the rest is not read.
  std::vector<std::uint8_t> padded = gvcp_datagram(0x0080, 4, {0x1F0, 0xFFFFFFFF});
  EXPECT_EQ(check(padded).verdict, gvcp::Verdict::kAnswer);
}

// The acknowledgement's status of `datagram` sent with the id `id`, or -1 without one.
int acknowledged_status(test::GvcpClient& client, std::vector<std::uint8_t> datagram, std::uint16_t id) {
  datagram[6] = std::uint8_t(id >> 8);
  datagram[7] = std::uint8_t(id & 0xFF);
  if (!client.send(datagram)) return -1;
  for (auto ack = client.receive(2000ms); ack; ack = client.receive(2000ms))
    if (ack->size() >= 8 && (*ack)[6] == std::uint8_t(id >> 8) && (*ack)[7] == std::uint8_t(id & 0xFF))
      return ((*ack)[0] << 8) | (*ack)[1];
  return -1;
}

// The fake camera on 127.0.0.1, fed every malformed shape: none crashes or wedges it; the
// well-formed read that follows is answered; the driver opens it and takes a frame.
TEST(GigeFakeCamera, SurvivesMalformedDatagramsAndStillServesAClient) {
  test::GigeHostLock lock;
  if (!sim::gvcp_port_free("127.0.0.1"))
    GTEST_SKIP() << "another program holds UDP port 3956 (GVCP) on 127.0.0.1";
  sim::GigeFakeDetectorOptions o;
  o.serial = "LFGV-FUZZ";
  o.rows = 48;
  o.cols = 64;
  o.frame_rate_hz = 100;
  sim::GigeFakeDetector camera(o, [](std::uint64_t k, std::uint16_t* pixels, int rows, int cols) {
    for (int i = 0; i < rows * cols; ++i) pixels[i] = std::uint16_t(k + std::uint64_t(i));
  });
  const Status started = camera.start();
  ASSERT_TRUE(started.ok()) << started.to_string();
  test::GvcpClient client("127.0.0.1");
  const auto malformed = test::malformed_gvcp_datagrams();
  // One at a time, each followed by a well-formed read of the camera's test register
  // (arvfakecamera.h: 0x1F0 holds 0x12345678): the camera answers after every one.
  for (std::size_t i = 0; i < malformed.size(); ++i) {
    ASSERT_TRUE(client.send(malformed[i])) << "datagram " << i << ", " << malformed[i].size() << " bytes";
    const std::optional<std::uint32_t> value = client.read_register(0x1F0, std::uint16_t(100 + i), 5000ms);
    ASSERT_TRUE(value.has_value()) << "no answer after datagram " << i << " (" << malformed[i].size()
                                   << " bytes)";
    EXPECT_EQ(*value, 0x12345678u);
  }
  EXPECT_TRUE(camera.running());
  EXPECT_EQ(camera.malformed(), malformed.size()) << "each dropped or refused";

  drivers::GigeDetectorOptions d;
  d.camera = camera.address();
  d.rows = o.rows;
  d.cols = o.cols;
  drivers::GigeDetector detector(d);
  const Status opened = detector.open();
  ASSERT_TRUE(opened.ok()) << opened.to_string();
  // A stranger's malformed datagrams while the driver holds control change nothing for it.
  for (const auto& m : malformed) client.send(m);
  drivers::Frame f;
  f.pixels = tracking::Image<std::uint16_t>(o.rows, o.cols);
  drivers::DeviceStatus s = drivers::DeviceStatus::kTimeout;
  for (const auto until = std::chrono::steady_clock::now() + 2s;
       s != drivers::DeviceStatus::kOk && std::chrono::steady_clock::now() < until;)
    s = detector.capture(&f, test::in_ms(100));
  EXPECT_EQ(s, drivers::DeviceStatus::kOk);
  EXPECT_EQ(f.pixels.at(0, 1), std::uint16_t(f.pixels.at(0, 0) + 1));
  // Another client's write while the driver holds control is refused (access denied), not obeyed.
  std::vector<std::uint8_t> write = gvcp_datagram(0x0082, 8, {0x1F0, 0});
  write[6] = 0x09;  // its own id, told apart from the error acknowledges of the datagrams above
  write[7] = 0x99;
  ASSERT_TRUE(client.send(write));
  int status = -1;
  for (auto ack = client.receive(2000ms); ack && status < 0; ack = client.receive(2000ms))
    if (ack->size() >= 8 && (*ack)[3] == 0x83 && (*ack)[6] == 0x09 && (*ack)[7] == 0x99)
      status = ((*ack)[0] << 8) | (*ack)[1];
  EXPECT_EQ(status, 0x8006) << "GigE Vision's access denied";
  EXPECT_EQ(client.read_register(0x1F0, 8, 2000ms).value_or(0), 0x12345678u) << "the register kept its value";
  detector.close();
}

// Issue 50 probe: register writes were taken as written, a frame period of 0, a heartbeat
// timeout of 0xFFFFFFFF (a client that took control and left held the camera for 49 days) and the
// GenICam URL among them. Values outside what a panel's firmware accepts are refused
// (invalid parameter), a multi-register write is all or nothing, and a memory write cannot reach
// around the check; the camera keeps its schedule and serves on.
TEST(GigeFakeCamera, RefusesAbsurdRegisterValuesAndKeepsItsSchedule) {
  test::GigeHostLock lock;
  if (!sim::gvcp_port_free("127.0.0.1"))
    GTEST_SKIP() << "another program holds UDP port 3956 (GVCP) on 127.0.0.1";
  sim::GigeFakeDetectorOptions o;
  o.serial = "LFGV-BOUNDS";
  o.rows = 48;
  o.cols = 64;
  o.frame_rate_hz = 100;
  sim::GigeFakeDetector camera(o, [](std::uint64_t, std::uint16_t* pixels, int rows, int cols) {
    for (int i = 0; i < rows * cols; ++i) pixels[i] = 7;
  });
  ASSERT_TRUE(camera.start().ok());
  test::GvcpClient client("127.0.0.1");
  constexpr std::uint32_t kFramePeriodUs = 0x138;  // arvfakecamera.h: ACQUISITION_FRAME_PERIOD_US
  constexpr std::uint32_t kHeartbeatMs = 0x0938;
  const std::uint32_t heartbeat = client.read_register(kHeartbeatMs, 1, 2000ms).value_or(0);
  ASSERT_EQ(client.read_register(kFramePeriodUs, 2, 2000ms).value_or(0), 10'000u);
  std::uint16_t id = 0x0500;
  const auto status_of = [&](std::vector<std::uint8_t> datagram) {
    return acknowledged_status(client, datagram, ++id);
  };
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kFramePeriodUs, 0})), 0x8002) << "frame period 0";
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kFramePeriodUs, 1})), 0x8002) << "1 us";
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kHeartbeatMs, 0xFFFFFFFFu})), 0x8002) << "a heartbeat of 50 days";
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kHeartbeatMs, 0})), 0x8002) << "no heartbeat";
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 16, {0x1F0, 1, kFramePeriodUs, 0})), 0x8002)
      << "a good pair before a bad one";
  EXPECT_EQ(status_of(gvcp_datagram(0x0086, 8, {kFramePeriodUs & ~3u, 0})), 0x8004) << "memory over the register";
  const std::uint32_t url = client.read_register(0x0200, 7, 2000ms).value_or(0);
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {0x0200, 0xFFFFFFFFu})), 0x8004) << "the GenICam URL is read-only";
  EXPECT_EQ(status_of(gvcp_datagram(0x0086, 8, {0x0000, 0xFFFFFFFFu})), 0x8004) << "so is the bootstrap's version";
  EXPECT_EQ(client.read_register(0x0200, 8, 2000ms).value_or(0), url);
  // The image registers take only what the panel gives (second probe: width 0 was acknowledged).
  constexpr std::uint32_t kWidth = 0x100, kHeight = 0x104, kPixelFormat = 0x128, kSensorWidth = 0x11c;
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kWidth, 0})), 0x8002) << "width 0";
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kHeight, 99999})), 0x8002) << "height beyond the rows";
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kPixelFormat, 0xDEADBEEFu})), 0x8002) << "no such format";
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kSensorWidth, 1})), 0x8004) << "the sensor's size";
  EXPECT_EQ(client.read_register(kWidth, 9, 2000ms).value_or(0), 64u);
  EXPECT_EQ(client.read_register(0x1F0, 3, 2000ms).value_or(0), 0x12345678u) << "all or nothing";
  EXPECT_EQ(client.read_register(kFramePeriodUs, 4, 2000ms).value_or(0), 10'000u);
  EXPECT_EQ(client.read_register(kHeartbeatMs, 5, 2000ms).value_or(0), heartbeat);
  EXPECT_EQ(camera.malformed(), 12u);
  // What a panel accepts is written.
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kFramePeriodUs, 20'000})), 0x0000);
  EXPECT_EQ(client.read_register(kFramePeriodUs, 6, 2000ms).value_or(0), 20'000u);
  EXPECT_EQ(status_of(gvcp_datagram(0x0082, 8, {kHeartbeatMs, 1000})), 0x0000);
  EXPECT_TRUE(camera.running());
}

// The camera's clock as GigE Vision's bootstrap registers give it: a tick frequency, a latch at
// 0x0944 (2 latches, 1 resets) and the latched 64 bits at 0x0948 / 0x094C, both read-only.
TEST(GigeFakeCamera, LatchesItsClockAsGigeVisionSays) {
  test::GigeHostLock lock;
  if (!sim::gvcp_port_free("127.0.0.1"))
    GTEST_SKIP() << "another program holds UDP port 3956 (GVCP) on 127.0.0.1";
  sim::GigeFakeDetectorOptions o;
  o.serial = "LFGV-LATCH";
  o.rows = 16;
  o.cols = 16;
  sim::GigeFakeDetector camera(o, [](std::uint64_t, std::uint16_t*, int, int) {});
  ASSERT_TRUE(camera.start().ok());
  test::GvcpClient client("127.0.0.1");
  std::uint16_t id = 0x0700;
  const auto write = [&](std::uint32_t address, std::uint32_t value) {
    return acknowledged_status(client, gvcp_datagram(0x0082, 8, {address, value}), ++id);
  };
  const auto latched_ns = [&](std::uint16_t read_id) {
    const std::uint64_t high = client.read_register(0x0948, read_id, 2000ms).value_or(0);
    const std::uint64_t low = client.read_register(0x094C, std::uint16_t(read_id + 1), 2000ms).value_or(0);
    return std::int64_t((high << 32) | low);
  };
  EXPECT_EQ(client.read_register(0x093C, 1, 2000ms).value_or(7), 0u);
  EXPECT_EQ(client.read_register(0x0940, 2, 2000ms).value_or(0), 1'000'000'000u) << "1 GHz ticks";
  EXPECT_EQ(latched_ns(3), 0) << "nothing latched yet";
  const auto realtime_ns = [] {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(
               std::chrono::system_clock::now().time_since_epoch())
        .count();
  };
  const std::int64_t before = realtime_ns();
  ASSERT_EQ(write(0x0944, 2), 0x0000);
  const std::int64_t after = realtime_ns();
  const std::int64_t first = latched_ns(5);
  EXPECT_GE(first, before - 1'000) << "the clock is the host's CLOCK_REALTIME, in whole us";
  EXPECT_LE(first, after);
  EXPECT_EQ(latched_ns(7), first) << "the value holds until the next latch";
  ASSERT_EQ(write(0x0944, 2), 0x0000);
  EXPECT_GE(latched_ns(9), first);
  // A reset moves the clock's zero: a latch just after reads a few ms at most.
  ASSERT_EQ(write(0x0944, 1), 0x0000);
  ASSERT_EQ(write(0x0944, 2), 0x0000);
  const std::int64_t since_reset = latched_ns(11);
  EXPECT_GE(since_reset, 0);
  EXPECT_LT(since_reset, 2'000'000'000) << "within the 2 s the acknowledgements may take";
  // Read-only: the tick frequency and the latched value.
  EXPECT_EQ(write(0x0940, 1), 0x8004);
  EXPECT_EQ(write(0x094C, 1), 0x8004);
  EXPECT_EQ(latched_ns(13), since_reset);
  EXPECT_TRUE(camera.running());
}

}  // namespace
}  // namespace lftrack
