// The closed loop watched from outside (issue 22): the monitor page with ten event streams and a
// stalled one open, and OpenIGTLink clients (one reading, one stalled), change nothing in the
// cycle: it still allocates nothing, tracks every cycle, and every transform a client receives is
// the journal's registration of that cycle.

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include "lftrack/loop/allocation_counter.hpp"
#include "lftrack/records/loop_json.hpp"
#include "loop_fixture.hpp"
// After Eigen: httplib.h brings in <resolv.h>, whose _res macro breaks Eigen's headers.
#include <httplib.h>

#include "igtl_test_client.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"

namespace lftrack::session {

using loop::exclude_this_thread_from_allocation_count;
using loop::JournalRecord;
using loop::LoopSummary;
using loop::process_allocation_count;

using watch::IgtlOptions;
using watch::MonitorOptions;
using watch::ras_from_lps;

using records::to_json;
namespace {

// A TCP client that connects and never reads (a stalled watcher).
int stalled_client(int port, const std::string& request) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  const int small = 1024;
  ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port));
  inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
  EXPECT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  if (!request.empty()) {
    EXPECT_EQ(::send(fd, request.data(), request.size(), 0), ssize_t(request.size()));
  }
  return fd;
}

// Every TRANSFORM an OpenIGTLink client receives until the server closes or `stop`.
struct IgtlReader {
  std::vector<std::pair<std::string, Eigen::Matrix4d>> transforms;
  std::thread thread;
  std::atomic<bool> stop{false};
  explicit IgtlReader(int port) {
    thread = std::thread([this, port] {
      exclude_this_thread_from_allocation_count();  // stands for another process (3D Slicer)
      test::IgtlClient client(port);
      while (client.connected() && !client.closed() && !stop) {
        auto m = client.next(std::chrono::milliseconds(200));
        if (m && m->type == "TRANSFORM") transforms.emplace_back(m->device, m->matrix);
      }
    });
  }
  void finish() {
    stop = true;
    thread.join();
  }
};

TEST_F(ClosedLoop, APageWithTenClientsAndOpenIgtlinkChangeNothingInTheCycle) {
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.allocation_count = &process_allocation_count;
  MonitorOptions monitor;
  monitor.listen = {"127.0.0.1", 0};
  monitor.token_dir = dir_.path();
  options.monitor = monitor;
  IgtlOptions igtl;
  igtl.listen = {"127.0.0.1", 0};
  options.igtl = igtl;
  std::vector<std::thread> pages;
  std::atomic<bool> done{false};
  std::atomic<int> events_seen{0};
  std::unique_ptr<IgtlReader> reader;
  std::vector<int> stalled;
  const LoopRun r = run_loop(kBreathing, 300, options, kLightFieldFrames, [&](LoopSession& session) {
    const int http = session.monitor()->port();
    const int igtl_port = session.igtl()->port();
    for (int i = 0; i < 10; ++i)
      pages.emplace_back([&, http] {
        exclude_this_thread_from_allocation_count();  // stands for a browser, another process
        httplib::Client c("127.0.0.1", http);
        c.set_read_timeout(2, 0);
        while (!done) {
          c.Get("/api/events", [&](const char*, std::size_t) {
            ++events_seen;
            return !done.load();
          });
          std::this_thread::sleep_for(std::chrono::milliseconds(20));  // the server went with the session
        }
      });
    stalled.push_back(stalled_client(http, "GET /api/events HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(http) + "\r\n\r\n"));
    stalled.push_back(stalled_client(igtl_port, ""));
    reader = std::make_unique<IgtlReader>(igtl_port);
    // Every client is connected before the first cycle (the 10 pages and the stalled one on the
    // monitor; the stalled one and the reader on OpenIGTLink), or the test says which is not.
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(30);
    while ((session.monitor()->counters().event_clients < 11 || session.igtl()->counters().clients_now < 2) &&
           std::chrono::steady_clock::now() < until)
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    EXPECT_EQ(session.monitor()->counters().event_clients, 11);
    EXPECT_EQ(session.igtl()->counters().clients_now, 2);
    return std::thread([] {});
  });
  // The page's clients were served while the loop ran; stop them, then compare.
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  done = true;
  for (auto& t : pages) t.join();
  reader->finish();
  for (int fd : stalled) ::close(fd);
  const LoopSummary& s = r.summary;
  SCOPED_TRACE(to_json(s).dump());
  expect_tracks_every_cycle(s, 300);
  ASSERT_TRUE(s.allocations_per_cycle.has_value());
  EXPECT_EQ(*s.allocations_per_cycle, 0.0) << "the cycle's threads allocate nothing with the page open";
  EXPECT_GT(events_seen.load(), 10);
  // Every registration in the journal reached the OpenIGTLink client, in order, as it was.
  std::vector<Eigen::Matrix4d> poses;
  for (const auto& [device, m] : reader->transforms)
    if (device == "T_room_from_ct") poses.push_back(m);
  // The journal leaves a cycle's similarity 0 when it did not register (a time-boxed failure).
  std::vector<const JournalRecord*> registered;
  for (const JournalRecord& rec : r.journal.records)
    if (rec.similarity[0] != 0) registered.push_back(&rec);
  EXPECT_GE(registered.size(), 290u);
  ASSERT_EQ(poses.size(), registered.size()) << "a pose per registered cycle";
  for (std::size_t i = 0; i < poses.size(); ++i) {
    Eigen::Map<const tracking::Vector6d> delta(registered[i]->pose_delta);
    const Eigen::Matrix4d expected = ras_from_lps(
        tracking::apply_delta(scene_->nominal_T_room_from_ct, tracking::PoseDelta::from_vector(delta),
                              scene_->registration_origin_room_mm())
            .matrix());
    ASSERT_LT((poses[i] - expected).cwiseAbs().maxCoeff(), 2e-3) << "cycle " << registered[i]->cycle;
  }
  std::size_t corrections = 0, sent = 0;
  for (const auto& t : reader->transforms) corrections += t.first == "Correction";
  for (const JournalRecord& rec : r.journal.records) sent += rec.command_sent;
  EXPECT_EQ(corrections, sent);
}

}  // namespace
}  // namespace lftrack::session
