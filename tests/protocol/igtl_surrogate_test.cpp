// The optical tracker's OpenIGTLink client (drivers/igtl_surrogate.hpp) against real peers on
// loopback: the tracker's twin (sim/tracker_twin.hpp) in process (as a process of its own:
// served_tracker_test.cpp), and a hand-made peer that sends what a tracker should not: stale,
// future, repeated and non-finite readings, a bad CRC, an absurd body size, other messages.

#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <igtlPositionMessage.h>
#include <igtlStringMessage.h>
#include <igtlTransformMessage.h>
#include <igtl_util.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include "igtl_test_support.hpp"
#include "lftrack/drivers/igtl_surrogate.hpp"
#include "lftrack/loop/allocation_counter.hpp"
#include "lftrack/sim/tracker_twin.hpp"

namespace lftrack {
namespace {

using namespace std::chrono_literals;
using drivers::IgtlSurrogateOptions;
using drivers::IgtlSurrogateSource;
using drivers::SurrogateReading;
using test::client_of;
using test::igtl_clock_ns;
using test::mono_ns;
using test::read_until;

// Waits until `condition` holds, or 20 s.
template <class Condition>
bool eventually(Condition&& condition) {
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(2ms);
  }
  return true;
}

// The bytes of a TRANSFORM (or POSITION) message for `ras`, stamped at `wall_ns`; 0: no time stamp.
std::string marker_bytes(const Eigen::Vector3d& ras, std::int64_t wall_ns, bool position = false,
                         const char* device = "Marker") {
  igtl::MessageBase::Pointer m;
  float p[3] = {float(ras.x()), float(ras.y()), float(ras.z())};
  if (position) {
    igtl::PositionMessage::Pointer pm = igtl::PositionMessage::New();
    pm->SetPackType(igtl::PositionMessage::ALL);
    pm->SetPosition(p);
    m = pm;
  } else {
    igtl::TransformMessage::Pointer tm = igtl::TransformMessage::New();
    tm->SetPosition(p);
    m = tm;
  }
  m->SetDeviceName(device);
  igtl::TimeStamp::Pointer stamp = igtl::TimeStamp::New();
  stamp->SetTime(static_cast<igtlUint32>(wall_ns / 1'000'000'000),
                 static_cast<igtlUint32>(wall_ns % 1'000'000'000));
  m->SetTimeStamp(stamp);
  m->Pack();
  std::string bytes(static_cast<const char*>(m->GetPackPointer()), std::size_t(m->GetPackSize()));
  if (wall_ns == 0) std::fill(bytes.begin() + 34, bytes.begin() + 42, '\0');  // the header's time stamp
  return bytes;
}

// A POSITION without orientation (12 bytes of body), as some trackers send: cut from the library's
// 28-byte form, with the header's body size and CRC set for what is left.
std::string short_position_bytes(const Eigen::Vector3d& ras, std::int64_t wall_ns) {
  std::string bytes = marker_bytes(ras, wall_ns, /*position=*/true);
  bytes.resize(58 + 12);
  auto* b = reinterpret_cast<unsigned char*>(bytes.data());
  const std::uint64_t crc = ::crc64(b + 58, 12, 0);
  for (int i = 0; i < 8; ++i) {
    b[42 + i] = static_cast<unsigned char>(std::uint64_t{12} >> (56 - 8 * i));
    b[50 + i] = static_cast<unsigned char>(crc >> (56 - 8 * i));
  }
  return bytes;
}

// The same message under OpenIGTLink 3's header version 2: an extended header (12 bytes) and a
// metadata header before and after the content, the CRC over all of it.
std::string version2_bytes(const std::string& v1) {
  std::string body(12, '\0');
  body[1] = 12;                    // the extended header's size
  body += v1.substr(58);           // the content
  body += std::string("\0\0", 2);  // a metadata header of no entries (2 bytes: their count)
  body[3] = 2;                     // metadata header size
  std::string bytes = v1.substr(0, 58) + body;
  auto* b = reinterpret_cast<unsigned char*>(bytes.data());
  b[0] = 0;
  b[1] = 2;
  const std::uint64_t size = body.size(), crc = ::crc64(b + 58, size, 0);
  for (int i = 0; i < 8; ++i) {
    b[42 + i] = static_cast<unsigned char>(size >> (56 - 8 * i));
    b[50 + i] = static_cast<unsigned char>(crc >> (56 - 8 * i));
  }
  return bytes;
}

std::int64_t wall_ns_ago(double seconds) {
  return igtl_clock_ns(CLOCK_REALTIME) - std::int64_t(seconds * 1e9);
}

// A peer that listens on loopback and sends what the test gives it to its newest connection.
class HandPeer {
 public:
  HandPeer() {
    listen_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in at{};
    at.sin_family = AF_INET;
    at.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(::bind(listen_, reinterpret_cast<sockaddr*>(&at), sizeof at), 0);
    EXPECT_EQ(::listen(listen_, 4), 0);
    socklen_t length = sizeof at;
    getsockname(listen_, reinterpret_cast<sockaddr*>(&at), &length);
    port_ = ntohs(at.sin_port);
  }
  ~HandPeer() {
    for (const int fd : connections_) ::close(fd);
    ::close(listen_);
  }
  int port() const { return port_; }
  // Closes the newest connection (the server went away).
  void hang_up() {
    ::close(connections_.back());
    connections_.back() = -1;
  }
  // The next connection within 20 s (the client reconnects every retry_ms).
  bool accept_next() {
    pollfd p{listen_, POLLIN, 0};
    if (::poll(&p, 1, 20000) != 1) return false;
    connections_.push_back(::accept4(listen_, nullptr, nullptr, SOCK_CLOEXEC));
    return connections_.back() >= 0;
  }
  void send(const std::string& bytes) {
    ASSERT_EQ(::send(connections_.back(), bytes.data(), bytes.size(), MSG_NOSIGNAL), ssize_t(bytes.size()));
  }

 private:
  int listen_ = -1, port_ = 0;
  std::vector<int> connections_;
};

// A client that reconnects quickly, and refuses only readings seconds old: on a loaded host a
// message may wait a while before the test's peer sends it or the client reads it.
TEST(IgtlSurrogate, ReadsTheTrackersTransformsAtTheTimesTheyWereMeasured) {
  // The twin's marker says when it was measured: z is the milliseconds since t0 (room frame).
  const std::int64_t t0 = mono_ns();
  sim::TrackerTwinOptions twin;
  twin.rate_hz = 100;
  auto served = sim::TrackerTwin::start(twin, [t0](std::int64_t t_ns, Eigen::Vector3d* p) {
    *p = Eigen::Vector3d(3, -2, 1e-6 * double(t_ns - t0));
    return true;
  });
  ASSERT_TRUE(served.ok()) << served.status().message();
  IgtlSurrogateOptions o = client_of((*served)->port());
  o.device = "Marker";
  IgtlSurrogateSource z(o);
  ASSERT_TRUE(z.open().ok());
  const std::vector<SurrogateReading> got = read_until(z, 40);
  ASSERT_GE(got.size(), 40u);
  for (std::size_t i = 0; i < got.size(); ++i) {
    if (i > 0) {
      EXPECT_GT(got[i].t_ns, got[i - 1].t_ns);
    }
    // The reading's time is the message's time stamp, not its arrival: what z encodes.
    EXPECT_NEAR(1e-6 * double(got[i].t_ns - t0), got[i].amplitude, 2.0) << i;
    EXPECT_LE(got[i].t_ns, mono_ns());
  }
  EXPECT_GE(double(got.back().t_ns - got.front().t_ns) / double(got.size() - 1), 9.5e6) << "100 Hz at most";
  // OpenIGTLink is RAS, the room LPS-like: the twin's x = 3 and y = -2 read back in the room frame.
  const std::vector<std::pair<Eigen::Vector3d, double>> along_axes = {
      {Eigen::Vector3d::UnitX(), 3.0},
      {Eigen::Vector3d::UnitY(), -2.0},
      {Eigen::Vector3d(0.6, 0.8, 0), 0.6 * 3 - 0.8 * 2}};
  for (const auto& [axis, expected] : along_axes) {
    o.axis_room = axis;
    IgtlSurrogateSource along(o);
    ASSERT_TRUE(along.open().ok());
    const std::vector<SurrogateReading> r = read_until(along, 3);
    ASSERT_FALSE(r.empty());
    EXPECT_NEAR(r.back().amplitude, expected, 1e-5);
  }
  const drivers::IgtlSurrogateCounters c = z.counters();
  EXPECT_EQ(c.connections, 1);
  EXPECT_EQ(c.refused_stale + c.refused_future + c.refused_order + c.protocol_errors, 0);
}

TEST(IgtlSurrogate, ReadsPositionMessagesOfItsDeviceAndSkipsTheRest) {
  sim::TrackerTwinOptions twin;
  twin.rate_hz = 200;
  twin.device = "Probe";
  twin.position_messages = true;
  auto served = sim::TrackerTwin::start(twin, [](std::int64_t, Eigen::Vector3d* p) {
    *p = Eigen::Vector3d(0, 0, 7.5);
    return true;
  });
  ASSERT_TRUE(served.ok());
  IgtlSurrogateOptions o = client_of((*served)->port());
  o.device = "Marker";
  IgtlSurrogateSource other(o);
  ASSERT_TRUE(other.open().ok());
  ASSERT_TRUE(eventually([&] { return other.counters().ignored >= 20; }));
  SurrogateReading r[8];
  EXPECT_EQ(other.read(mono_ns(), r, 8), 0) << "another device's messages are not the marker's";
  o.device = "Probe";
  IgtlSurrogateSource probe(o);
  ASSERT_TRUE(probe.open().ok());
  const std::vector<SurrogateReading> got = read_until(probe, 10);
  ASSERT_GE(got.size(), 10u);
  for (const SurrogateReading& s : got) EXPECT_EQ(s.amplitude, 7.5);
  EXPECT_EQ(probe.counters().protocol_errors, 0);
}

TEST(IgtlSurrogate, HonoursTimeStampsAndRefusesStaleFutureAndRepeatedReadings) {
  HandPeer peer;
  IgtlSurrogateSource s(client_of(peer.port()));
  ASSERT_TRUE(s.open().ok());
  ASSERT_TRUE(peer.accept_next());
  // Measured 100 ms before it was sent: its time is then, not its arrival.
  const std::int64_t sent_mono = mono_ns();
  const std::int64_t stamp = wall_ns_ago(0.1);
  peer.send(marker_bytes({0, 0, 1}, stamp));
  ASSERT_TRUE(eventually([&] { return s.counters().readings == 1; }));
  SurrogateReading r[8];
  ASSERT_EQ(s.read(mono_ns(), r, 8), 1);
  EXPECT_NEAR(double(r[0].t_ns - sent_mono), -1e8, 5e7) << "the time stamp, on this host's monotonic clock";
  EXPECT_EQ(r[0].amplitude, 1);
  // Ten seconds old, ten ahead, and the same time again: each refused, and counted.
  peer.send(marker_bytes({0, 0, 2}, wall_ns_ago(10.0)));
  peer.send(marker_bytes({0, 0, 3}, wall_ns_ago(-10.0)));
  peer.send(marker_bytes({0, 0, 4}, stamp));
  ASSERT_TRUE(eventually([&] {
    const auto c = s.counters();
    return c.refused_stale == 1 && c.refused_future == 1 && c.refused_order == 1;
  })) << "stale "
      << s.counters().refused_stale << ", future " << s.counters().refused_future << ", order "
      << s.counters().refused_order << ", readings " << s.counters().readings;
  // A NaN position is passed on: the loop's watch holds on it. No time stamp: measured when it came
  // (a POSITION without orientation, 12 bytes).
  peer.send(marker_bytes({0, 0, std::numeric_limits<double>::quiet_NaN()}, wall_ns_ago(0)));
  const std::int64_t before = mono_ns();
  peer.send(short_position_bytes({0, 0, 5}, 0));
  ASSERT_TRUE(eventually([&] { return s.counters().readings == 3; }))
      << "readings " << s.counters().readings << ", protocol errors " << s.counters().protocol_errors
      << ", order " << s.counters().refused_order << ", stale " << s.counters().refused_stale;
  ASSERT_EQ(s.read(mono_ns(), r, 8), 2);
  EXPECT_TRUE(std::isnan(r[0].amplitude));
  EXPECT_GE(r[1].t_ns, before);
  EXPECT_EQ(r[1].amplitude, 5);
  EXPECT_EQ(s.counters().protocol_errors, 0);
}

TEST(IgtlSurrogate, GivesTheNewestWhenAskedForFewerAndNothingFromTheFuture) {
  HandPeer peer;
  IgtlSurrogateSource s(client_of(peer.port()));
  ASSERT_TRUE(s.open().ok());
  ASSERT_TRUE(peer.accept_next());
  const std::int64_t first = wall_ns_ago(0.05);
  for (int i = 1; i <= 5; ++i) peer.send(marker_bytes({0, 0, double(i)}, first + i * 1'000'000));
  ASSERT_TRUE(eventually([&] { return s.counters().readings == 5; }));
  SurrogateReading r[8];
  EXPECT_EQ(s.read(mono_ns() - 1'000'000'000, r, 8), 0) << "none measured a second ago: they wait";
  ASSERT_EQ(s.read(mono_ns(), r, 2), 2);
  EXPECT_EQ(r[0].amplitude, 4);
  EXPECT_EQ(r[1].amplitude, 5);
  EXPECT_EQ(s.read(mono_ns(), r, 8), 0) << "each reading is given once";
}

// The reader's thread feeds the cycle: once connected, a message read and handed over allocates
// nothing (the counter is the whole process's; the peer's messages are packed beforehand).
TEST(IgtlSurrogate, ReadsAndHandsOverWithoutAllocating) {
  HandPeer peer;
  IgtlSurrogateSource s(client_of(peer.port()));
  ASSERT_TRUE(s.open().ok());
  ASSERT_TRUE(peer.accept_next());
  std::vector<std::string> messages;
  const std::int64_t first = wall_ns_ago(0.15);
  for (int i = 0; i < 200; ++i)
    messages.push_back(marker_bytes({0, 0, double(i)}, first + i * 500'000, /*position=*/i % 2 == 1));
  for (int i = 0; i < 10; ++i) peer.send(messages[std::size_t(i)]);
  ASSERT_TRUE(eventually([&] { return s.counters().readings == 10; }));
  SurrogateReading r[64];
  const std::uint64_t before = loop::process_allocation_count();
  for (std::size_t i = 10; i < messages.size(); ++i) peer.send(messages[i]);
  ASSERT_TRUE(eventually([&] { return s.counters().readings == 200; }));
  int given = 0;
  for (int n; (n = s.read(mono_ns(), r, 64)) > 0;) given += n;
  EXPECT_EQ(loop::process_allocation_count() - before, 0u);
  EXPECT_EQ(given, 64) << "the newest 64 of 200";
  EXPECT_EQ(r[63].amplitude, 199);
}

TEST(IgtlSurrogate, DropsAPeerThatIsNotOpenIgtlinkAndReconnects) {
  HandPeer peer;
  IgtlSurrogateSource s(client_of(peer.port()));
  ASSERT_TRUE(s.open().ok());
  ASSERT_TRUE(peer.accept_next());
  // A header claiming a body of 2^40 bytes.
  std::string huge = marker_bytes({0, 0, 1}, wall_ns_ago(0));
  for (int i = 42; i < 50; ++i) huge[std::size_t(i)] = i == 44 ? '\x01' : '\0';
  peer.send(huge);
  ASSERT_TRUE(peer.accept_next()) << "the client reconnects";
  EXPECT_EQ(s.counters().protocol_errors, 1);
  // A body that fails its CRC.
  std::string bad = marker_bytes({0, 0, 1}, wall_ns_ago(0));
  bad[60] = char(bad[60] ^ 0x5a);
  peer.send(bad);
  ASSERT_TRUE(peer.accept_next());
  EXPECT_EQ(s.counters().protocol_errors, 2);
  // Another message type is skipped whole; the next marker is read.
  igtl::StringMessage::Pointer text = igtl::StringMessage::New();
  text->SetDeviceName("Marker");
  text->SetString(std::string(10000, 'x').c_str());
  text->Pack();
  peer.send(std::string(static_cast<const char*>(text->GetPackPointer()), std::size_t(text->GetPackSize())));
  peer.send(marker_bytes({0, 0, 6}, wall_ns_ago(0)));
  const std::vector<SurrogateReading> got = read_until(s, 1);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].amplitude, 6);
  EXPECT_EQ(s.counters().ignored, 1);
  EXPECT_EQ(s.counters().connections, 3);
  EXPECT_EQ(s.counters().readings, 1) << "nothing of the bad messages was taken";
}

TEST(IgtlSurrogate, RefusesToOpenWithoutATrackerAndSaysWhere) {
  // A port bound but not listening: refused, and no other test can take it meanwhile.
  const int bound = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in at{};
  at.sin_family = AF_INET;
  at.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ASSERT_EQ(::bind(bound, reinterpret_cast<sockaddr*>(&at), sizeof at), 0);
  socklen_t length = sizeof at;
  getsockname(bound, reinterpret_cast<sockaddr*>(&at), &length);
  const int port = ntohs(at.sin_port);
  IgtlSurrogateSource s(client_of(port));
  const Status opened = s.open();
  ASSERT_FALSE(opened.ok());
  EXPECT_NE(opened.message().find("127.0.0.1:" + std::to_string(port)), std::string::npos)
      << opened.message();
  EXPECT_NE(opened.message().find("is it running"), std::string::npos) << opened.message();
  IgtlSurrogateOptions nowhere = client_of(port);
  nowhere.host = "no-such-host.invalid";
  EXPECT_FALSE(IgtlSurrogateSource(nowhere).open().ok());
  nowhere = client_of(port);
  nowhere.axis_room = Eigen::Vector3d(std::numeric_limits<double>::quiet_NaN(), 0, 0);
  EXPECT_FALSE(IgtlSurrogateSource(nowhere).open().ok());
  ::close(bound);
}

// OpenIGTLink 3's header version 2 (an extended header and metadata around the content) is read;
// with no device named, a second device on the stream stops every reading (PLUS sends each tool,
// the reference among them: following whichever came first could follow the wrong one).
TEST(IgtlSurrogate, ReadsVersionTwoHeadersAndRefusesAStreamOfSeveralUnnamedDevices) {
  HandPeer peer;
  IgtlSurrogateSource s(client_of(peer.port()));
  ASSERT_TRUE(s.open().ok());
  ASSERT_TRUE(peer.accept_next());
  const std::int64_t t = wall_ns_ago(0.01);
  peer.send(version2_bytes(marker_bytes({0, 0, 4}, t)));
  peer.send(version2_bytes(marker_bytes({0, 0, 5}, t + 1'000'000, /*position=*/true)));
  ASSERT_TRUE(eventually([&] { return s.counters().readings == 2; })) << s.counters().protocol_errors;
  SurrogateReading r[8];
  ASSERT_EQ(s.read(mono_ns(), r, 8), 2);
  EXPECT_EQ(r[0].amplitude, 4);
  EXPECT_EQ(r[1].amplitude, 5);
  peer.send(marker_bytes({0, 0, 6}, t + 2'000'000, false, "Reference"));
  peer.send(marker_bytes({0, 0, 7}, t + 3'000'000));
  ASSERT_TRUE(eventually([&] { return s.counters().ignored == 2; }));
  EXPECT_TRUE(s.counters().several_devices);
  EXPECT_EQ(s.read(mono_ns(), r, 8), 0) << "nothing taken once the stream is ambiguous";
  EXPECT_EQ(s.counters().protocol_errors, 0);
}

// A server that goes silent, or accepts and hangs up at once, is asked again every retry_ms, not
// in a tight loop.
TEST(IgtlSurrogate, ReconnectsAfterSilenceAndPacesAServerThatHangsUp) {
  HandPeer peer;
  IgtlSurrogateOptions o = client_of(peer.port());
  o.idle_ms = 300;
  o.retry_ms = 100;
  IgtlSurrogateSource s(o);
  ASSERT_TRUE(s.open().ok());
  ASSERT_TRUE(peer.accept_next());
  ASSERT_TRUE(peer.accept_next()) << "nothing for idle_ms: the client connects again";
  const auto start = std::chrono::steady_clock::now();
  for (int i = 0; i < 5; ++i) {
    peer.hang_up();
    ASSERT_TRUE(peer.accept_next());
  }
  EXPECT_GE(std::chrono::steady_clock::now() - start, 5 * 90ms) << "retry_ms between connections";
  EXPECT_EQ(s.counters().protocol_errors, 0);
}

}  // namespace
}  // namespace lftrack
