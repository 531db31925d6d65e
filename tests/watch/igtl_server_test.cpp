// The OpenIGTLink server (igtl_server.hpp) against the library's own client (igtl::ClientSocket
// and its message classes, as 3D Slicer's OpenIGTLinkIF uses them): transforms and state changes
// per cycle, in RAS, and a stalled client that is dropped while another keeps receiving.

#include "lftrack/watch/igtl_server.hpp"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cstring>

#include "igtl_test_client.hpp"
#include "watch_fixture.hpp"

namespace lftrack::watch {

using loop::FeedRecord;
using loop::TrackingState;
namespace {

using test_watch::HubOnFeed;
using test_watch::record;

using test::IgtlClient;
using test::IgtlMessage;

bool wait_until(const std::function<bool()>& condition) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(3);
  while (!condition()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return true;
}

// A server on `h`'s hub (up to 8 clients) and one client it has accepted.
struct ServedClient {
  std::unique_ptr<IgtlServer> server;
  std::unique_ptr<IgtlClient> client;
};
void serve_one_client(HubOnFeed& h, ServedClient* out, bool simulated_clock = false) {
  auto server = IgtlServer::start(h.hub.get(), {{"127.0.0.1", 0}, 8, simulated_clock});
  ASSERT_TRUE(server.ok()) << server.status().message();
  out->server = std::move(server).value();
  out->client = std::make_unique<IgtlClient>(out->server->port());
  ASSERT_TRUE(out->client->connected());
  ASSERT_TRUE(wait_until([&] { return out->server->counters().clients_now == 1; }));
}

TEST(IgtlServer, SendsEachCyclesPoseCorrectionAndStateChangesInRas) {
  HubOnFeed h;
  ServedClient s;
  ASSERT_NO_FATAL_FAILURE(serve_one_client(h, &s));
  IgtlServer* server = s.server.get();
  IgtlClient& client = *s.client;
  h.publish(record(10, TrackingState::kTrack, TrackingState::kTrack, 1.5, true));
  h.publish(record(11, TrackingState::kTrack, TrackingState::kHold, 9.0, false, 123456));
  FeedRecord unregistered = record(12, TrackingState::kHold, TrackingState::kHold, 0, false, 123456);
  unregistered.registered = false;
  h.publish(unregistered);
  h.publish(record(13, TrackingState::kHold, TrackingState::kTrack, 0.2, true));
  const Eigen::Vector3d origin(1, 2, 3);
  auto expected_pose = [&](double tx) {
    tracking::Vector6d d = tracking::Vector6d::Zero();
    d(0) = tx;
    d(5) = 0.5 * 3.14159265358979 / 180;
    return ras_from_lps(tracking::apply_delta(tracking::Pose::Identity(), tracking::PoseDelta::from_vector(d), origin).matrix());
  };
  auto expected_correction = [&](double ty) {
    tracking::Vector6d d = tracking::Vector6d::Zero();
    d(1) = ty;
    return ras_from_lps(tracking::apply_delta(tracking::Pose::Identity(), tracking::PoseDelta::from_vector(d), origin).matrix());
  };
  // Cycle 10: pose and correction; 11: pose and the HOLD; 12: nothing (no registration, no
  // change); 13: pose, correction and TRACK.
  const std::vector<std::pair<std::string, std::string>> order = {
      {"TRANSFORM", "T_room_from_ct"}, {"TRANSFORM", "Correction"},     {"TRANSFORM", "T_room_from_ct"},
      {"STATUS", "lftrack"},           {"TRANSFORM", "T_room_from_ct"}, {"TRANSFORM", "Correction"},
      {"STATUS", "lftrack"}};
  std::vector<IgtlMessage> got;
  for (std::size_t i = 0; i < order.size(); ++i) {
    auto m = client.next();
    ASSERT_TRUE(m) << "message " << i;
    EXPECT_EQ(m->type, order[i].first) << i;
    EXPECT_EQ(m->device, order[i].second) << i;
    got.push_back(*m);
  }
  EXPECT_LT((got[0].matrix - expected_pose(1.5)).cwiseAbs().maxCoeff(), 1e-5);
  EXPECT_LT((got[1].matrix - expected_correction(-1.5)).cwiseAbs().maxCoeff(), 1e-5);
  EXPECT_LT((got[2].matrix - expected_pose(9.0)).cwiseAbs().maxCoeff(), 1e-5);
  EXPECT_EQ(got[3].code, igtl::StatusMessage::STATUS_DISABLED);
  EXPECT_EQ(got[3].error_name, "HOLD");
  EXPECT_EQ(got[3].subcode, 11);
  EXPECT_NE(got[3].status.find("gate"), std::string::npos) << got[3].status;
  EXPECT_EQ(got[6].code, igtl::StatusMessage::STATUS_OK);
  EXPECT_EQ(got[6].error_name, "TRACK");
  EXPECT_FALSE(client.next(std::chrono::milliseconds(300))) << "nothing more";
  // A client that connects now is told the state at once.
  IgtlClient late(server->port());
  ASSERT_TRUE(late.connected());
  auto first = late.next();
  ASSERT_TRUE(first);
  EXPECT_EQ(first->type, "STATUS");
  EXPECT_EQ(first->error_name, "TRACK");
}

double wall_now_s() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

// Every message carries the time of what it reports, STATUS too (an outside probe found STATUS
// messages stamped 1989): a cycle's messages its newest frame's exposure, the state told to a
// client on connecting the moment it connected.
TEST(IgtlServer, EveryMessageCarriesTheTimeOfWhatItReports) {
  HubOnFeed h;
  ServedClient s;
  ASSERT_NO_FATAL_FAILURE(serve_one_client(h, &s));
  timespec mono{};
  clock_gettime(CLOCK_MONOTONIC, &mono);
  const std::int64_t exposure_ns = std::int64_t{mono.tv_sec} * 1'000'000'000 + mono.tv_nsec - 2'000'000'000;  // 2 s ago
  FeedRecord held = record(20, TrackingState::kTrack, TrackingState::kHold, 9.0, true, 123456);
  held.record.frame_time_ns[0] = exposure_ns - 5'000'000;
  held.record.frame_time_ns[1] = exposure_ns;
  const double published_at_s = wall_now_s();
  h.publish(held);
  for (const char* type : {"TRANSFORM", "TRANSFORM", "STATUS"}) {
    auto m = s.client->next();
    ASSERT_TRUE(m) << type;
    EXPECT_EQ(m->type, type);
    EXPECT_NEAR(m->timestamp_s, published_at_s - 2.0, 0.5) << m->type << " " << m->device << ": the exposure's time";
  }
  IgtlClient late(s.server->port());
  ASSERT_TRUE(late.connected());
  auto first = late.next();
  ASSERT_TRUE(first);
  EXPECT_EQ(first->type, "STATUS");
  EXPECT_NEAR(first->timestamp_s, wall_now_s(), 5.0) << "the state when the client connected";
}

// Issue 50 probe: under `sim --fast` the stamps were the simulated exposure times carried onto the
// wall clock, minutes ahead of it by the end of a run. On the simulated clock a message is
// stamped with the wall time it is sent.
TEST(IgtlServer, OnTheSimulatedClockMessagesCarryTheWallTimeTheyAreSent) {
  HubOnFeed h;
  ServedClient s;
  ASSERT_NO_FATAL_FAILURE(serve_one_client(h, &s, /*simulated_clock=*/true));
  timespec mono{};
  clock_gettime(CLOCK_MONOTONIC, &mono);
  const std::int64_t ahead_ns = std::int64_t{mono.tv_sec} * 1'000'000'000 + mono.tv_nsec + 300'000'000'000;
  FeedRecord fast = record(3000, TrackingState::kTrack, TrackingState::kTrack, 1.0, true);
  fast.record.frame_time_ns[0] = fast.record.frame_time_ns[1] = ahead_ns;  // 5 simulated minutes ahead
  h.publish(fast);
  auto m = s.client->next();
  ASSERT_TRUE(m);
  EXPECT_NEAR(m->timestamp_s, wall_now_s(), 5.0) << "sent now, not 300 s from now";
}

// A session that ends (LoopSession::run) lets the hub and the server catch up before the server
// closes: a client gets every cycle the loop published, up to the last, then the end of stream.
TEST(IgtlServer, CatchingUpBeforeClosingSendsTheLastCycles) {
  HubOnFeed h;
  ServedClient s;
  ASSERT_NO_FATAL_FAILURE(serve_one_client(h, &s));
  IgtlServer* server = s.server.get();
  IgtlClient& client = *s.client;
  EXPECT_FALSE(server->catch_up(1, std::chrono::milliseconds(20))) << "no cycle published yet";
  constexpr int kCycles = 80;  // within the hub's history (100): nothing is skipped
  for (int c = 0; c < kCycles; ++c)
    h.feed.publish_record(record(std::uint64_t(c), TrackingState::kTrack, TrackingState::kTrack, 0.1, true).record,
                          true);
  const std::uint64_t seq = h.hub->catch_up(std::chrono::seconds(5));
  EXPECT_EQ(seq, std::uint64_t(kCycles));
  EXPECT_TRUE(server->catch_up(seq, std::chrono::seconds(5)));
  s.server.reset();  // closes at once, as a session's end destroys it
  int transforms = 0;
  while (auto m = client.next(std::chrono::milliseconds(2000)))
    if (m->type == "TRANSFORM") ++transforms;
  EXPECT_EQ(transforms, 2 * kCycles) << "a pose and a correction for every cycle";
  EXPECT_TRUE(client.closed());
}

TEST(IgtlServer, RasIsXAndYNegatedOnBothSides) {
  tracking::Pose T = tracking::Pose::Identity();
  T.translation() << 10, 20, 30;
  const Eigen::Matrix4d ras = ras_from_lps(T.matrix());
  EXPECT_EQ(ras(0, 3), -10);
  EXPECT_EQ(ras(1, 3), -20);
  EXPECT_EQ(ras(2, 3), 30);
  EXPECT_TRUE((ras.topLeftCorner<3, 3>().isIdentity()));
}

TEST(IgtlServer, AStalledClientIsDroppedAndAnotherKeepsReceiving) {
  HubOnFeed h;
  auto server = IgtlServer::start(h.hub.get(), {{"127.0.0.1", 0}, 8});
  ASSERT_TRUE(server.ok());
  // A client that connects and never reads, with a small receive buffer.
  const int stalled = ::socket(AF_INET, SOCK_STREAM, 0);
  const int small = 1024;
  ::setsockopt(stalled, SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>((*server)->port()));
  inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
  ASSERT_EQ(::connect(stalled, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  IgtlClient reader((*server)->port());
  ASSERT_TRUE(reader.connected());
  ASSERT_TRUE(wait_until([&] { return (*server)->counters().clients_now == 2; }));
  std::atomic<int> transforms{0};
  std::atomic<bool> stop{false};
  std::thread reading([&] {
    while (!stop)
      if (auto m = reader.next(std::chrono::milliseconds(500)); m && m->type == "TRANSFORM") ++transforms;
  });
  // Cycles until the stalled client is dropped (at least 30,000, about 6 MB to each client: far
  // more than its buffers hold), however few of them a loaded host's server thread passes on.
  int cycles = 0;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (cycles < 30000 ||
         ((*server)->counters().clients_now != 1 && std::chrono::steady_clock::now() < until)) {
    h.feed.publish_record(
        record(std::uint64_t(cycles), TrackingState::kTrack, TrackingState::kTrack, 0.1, true).record, true);
    if (++cycles % 40 == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  const int kCycles = cycles;
  EXPECT_TRUE(wait_until([&] { return (*server)->counters().clients_now == 1; })) << "the stalled client was dropped";
  // Every cycle reached the reader but those the server itself fell behind on (published here far
  // faster than a loop runs, beyond the hub's history) and those the feed dropped (a hub that
  // fell a whole queue behind), each counted.
  const auto lost = [&] {
    return static_cast<int>((*server)->counters().records_skipped + h.feed.dropped_records());
  };
  EXPECT_TRUE(wait_until([&] { return transforms.load() == 2 * (kCycles - lost()); }))
      << "the reader got " << transforms.load() << " transforms; skipped " << (*server)->counters().records_skipped
      << ", dropped by the feed " << h.feed.dropped_records();
  EXPECT_GT(transforms.load(), kCycles / 10);
  stop = true;
  reading.join();
  ::close(stalled);
}

TEST(IgtlServer, ManyClientsAreBoundedAndADisconnectIsNoticed) {
  HubOnFeed h;
  auto server = IgtlServer::start(h.hub.get(), {{"127.0.0.1", 0}, 2});
  ASSERT_TRUE(server.ok());
  {
    IgtlClient a((*server)->port()), b((*server)->port()), c((*server)->port());
    ASSERT_TRUE(wait_until([&] { return (*server)->counters().clients_total == 3; }));
    EXPECT_EQ((*server)->counters().clients_now, 2) << "a third beyond max_clients is closed";
  }
  EXPECT_TRUE(wait_until([&] { return (*server)->counters().clients_now == 0; })) << "disconnects are noticed";
  EXPECT_FALSE(IgtlServer::start(h.hub.get(), {{"127.0.0.1", (*server)->port()}, 2}).ok()) << "port taken";
  EXPECT_FALSE(IgtlServer::start(h.hub.get(), {{"127.0.0.1", 0}, 0}).ok());
  EXPECT_FALSE(IgtlServer::start(nullptr, {{"127.0.0.1", 0}, 2}).ok());
}

}  // namespace
}  // namespace lftrack::watch
