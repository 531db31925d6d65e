// The monitor page's server on loopback (monitor_server.hpp), spoken to with cpp-httplib's client:
// the page and its headers, the state, hosts and origins, the operator's token and nonces with
// each refusal journaled, and server-sent events to many clients with a stalled one among them.

#include "lftrack/watch/monitor_server.hpp"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <httplib.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <fstream>
#include <thread>
#include <vector>
#include <nlohmann/json.hpp>

#include "test_data.hpp"
#include "watch_fixture.hpp"

namespace lftrack::watch {

using loop::BeamWithheld;
using loop::FeedRecord;
using loop::GateDecision;
using loop::GateReason;
using loop::JournalRecord;
using loop::OperatorCommand;
using loop::OperatorPoll;
using loop::OperatorRefusal;
using loop::OperatorView;
using loop::TrackingState;
namespace {

using test_watch::HubOnFeed;
using test_watch::PollingLoop;
using test_watch::record;

struct Served {
  test::TempDir dir;
  HubOnFeed hub;
  PageOperator page;
  std::unique_ptr<MonitorServer> server;
  explicit Served(int max_event_clients = 16) {
    MonitorOptions o;
    o.listen = {"127.0.0.1", 0};
    o.token_dir = dir.path();
    o.max_event_clients = max_event_clients;
    auto s = MonitorServer::start(hub.hub.get(), &page, o);
    EXPECT_TRUE(s.ok()) << s.status().message();
    server = std::move(s).value();
  }
  httplib::Client client() const {
    httplib::Client c("127.0.0.1", server->port());
    c.set_read_timeout(5, 0);
    return c;
  }
  // A nonce, asked for with the run's token (only the operator gets one).
  std::string nonce() const {
    auto res = client().Get("/api/nonce", {{"Authorization", "Bearer " + server->token()}});
    EXPECT_TRUE(res && res->status == 200);
    return res ? nlohmann::json::parse(res->body).value("nonce", "") : "";
  }
  // POSTs an action; the status and the JSON answer.
  std::pair<int, nlohmann::json> act(const std::string& action, const nlohmann::json& body,
                                     const std::string& token, const std::string& origin = "") const {
    return act_text(action, body.dump(), token, origin);
  }
  std::pair<int, nlohmann::json> act_text(const std::string& action, const std::string& body,
                                          const std::string& token, const std::string& origin = "") const {
    httplib::Headers headers;
    if (!token.empty()) headers.emplace("Authorization", "Bearer " + token);
    if (!origin.empty()) headers.emplace("Origin", origin);
    auto res = client().Post(("/api/" + action).c_str(), headers, body, "application/json");
    if (!res) return {0, {}};
    return {res->status, nlohmann::json::parse(res->body, nullptr, false)};
  }
};

TEST(MonitorServer, ServesThePageAndTheStateOnlyForItsOwnHost) {
  Served s;
  s.hub.publish(record(41, TrackingState::kTrack, TrackingState::kHold, 8.0, false, 123456));
  auto page = s.client().Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->body.find("lftrack monitor"), std::string::npos);
  EXPECT_EQ(page->get_header_value("X-Frame-Options"), "DENY") << "no page may frame the resume button";
  EXPECT_NE(page->get_header_value("Content-Security-Policy").find("frame-ancestors 'none'"), std::string::npos);
  for (const char* asset : {"/monitor.js", "/monitor.css"}) {
    auto res = s.client().Get(asset);
    ASSERT_TRUE(res) << asset;
    EXPECT_EQ(res->status, 200) << asset;
    EXPECT_GT(res->body.size(), 500u) << asset;
  }
  auto state = s.client().Get("/api/state");
  ASSERT_TRUE(state);
  ASSERT_EQ(state->status, 200);
  const auto j = nlohmann::json::parse(state->body);
  EXPECT_EQ(j["cycle"], 41);
  EXPECT_EQ(j["state"], "HOLD");
  EXPECT_EQ(j["hold_id"], 123456);
  EXPECT_EQ(j["gate"]["reason"], to_string(GateReason::kStepTooLarge));
  EXPECT_NEAR(j["offset"]["translation_mm"][0].get<double>(), 8.0, 1e-9);
  EXPECT_NEAR(j["offset"]["rotation_deg"][2].get<double>(), 0.5, 1e-6);
  EXPECT_EQ(j["counts"]["holds"], 1);
  EXPECT_EQ(j["transitions"].size(), 1u);
  EXPECT_EQ(j["beam_permit"], false);
  EXPECT_EQ(j["beam_withheld"], "") << "a HOLD's beam is off, not withheld";
  // An applied cycle that kept the beam off says why.
  FeedRecord withheld = record(42, TrackingState::kTrack, TrackingState::kTrack, 1.0, true);
  withheld.record.gate_decision = static_cast<std::uint8_t>(GateDecision::kApply);
  withheld.record.beam_withheld = static_cast<std::uint8_t>(BeamWithheld::kActuatorTravelling);
  s.hub.publish(withheld);
  const auto k = nlohmann::json::parse(s.client().Get("/api/state")->body);
  EXPECT_EQ(k["cycle"], 42);
  EXPECT_EQ(k["beam_withheld"], "actuator still travelling");
  EXPECT_EQ(k["gate"]["shown"], "APPLY");
  EXPECT_EQ(k["gate"]["applied"], true);
  EXPECT_TRUE(k["latency_chain_ms"].is_null()) << "no chain recorded (the simulated clock)";
  // A real-clock command: its chain link by link, exposure (the older frame) to acknowledgement.
  FeedRecord chained = record(44, TrackingState::kTrack, TrackingState::kTrack, 1.0, true);
  JournalRecord& c = chained.record;
  c.command_sent = 1;
  c.frame_time_ns[0] = c.frame_time_ns[1] = 1'000'000'000;
  c.frames_arrived_ns = 1'002'000'000;
  c.preprocessed_ns = 1'002'500'000;
  c.registered_ns = 1'010'500'000;
  c.gated_ns = 1'010'510'000;
  c.command_written_ns = 1'010'520'000;
  c.command_acked_ns = 1'010'620'000;
  s.hub.publish(chained);
  const auto l = nlohmann::json::parse(s.client().Get("/api/state")->body)["latency_chain_ms"];
  ASSERT_TRUE(l.is_object());
  EXPECT_NEAR(l["arrive"].get<double>(), 2.0, 1e-9);
  EXPECT_NEAR(l["register"].get<double>(), 8.0, 1e-9);
  EXPECT_NEAR(l["acknowledge"].get<double>(), 0.1, 1e-9);
  EXPECT_NEAR(l["total"].get<double>(), 10.62, 1e-9);
  // In HOLD the gate still judges each registration; an APPLY there moves nothing, and the page's
  // header must not read "APPLY: ok" (an outside probe saw it do so during a HOLD).
  FeedRecord held = record(43, TrackingState::kHold, TrackingState::kHold, 1.0, false, 123456);
  held.record.gate_decision = static_cast<std::uint8_t>(GateDecision::kApply);
  held.record.gate_reason = static_cast<std::uint8_t>(GateReason::kOk);
  s.hub.publish(held);
  const auto h = nlohmann::json::parse(s.client().Get("/api/state")->body);
  EXPECT_EQ(h["gate"]["decision"], "APPLY") << "the record as the loop wrote it";
  EXPECT_EQ(h["gate"]["applied"], false);
  EXPECT_EQ(h["gate"]["shown"], "none (HOLD)");
  EXPECT_NE(h["gate"]["shown_reason"].get<std::string>().find("nothing is sent in HOLD"), std::string::npos);
  EXPECT_EQ(s.client().Get("/nothing")->status, 404);
  // Another host name (a page elsewhere resolving its name to this host) is answered nothing.
  auto rebound = s.client().Get("/api/state", {{"Host", "attacker.example:" + std::to_string(s.server->port())}});
  ASSERT_TRUE(rebound);
  EXPECT_EQ(rebound->status, 403);
  EXPECT_EQ(s.client().Get("/api/state", {{"Host", "localhost:" + std::to_string(s.server->port())}})->status, 200);
  // The token's file: this user's only.
  struct stat st {};
  ASSERT_EQ(::stat(s.server->token_file().c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  std::ifstream in(s.server->token_file());
  std::string token;
  std::getline(in, token);
  EXPECT_EQ(token, s.server->token());
}

TEST(MonitorServer, ActionsNeedTheTokenAFreshNonceAndThePagesOrigin) {
  Served s;
  OperatorView hold;
  hold.state = TrackingState::kHold;
  hold.hold_id = 123456;
  hold.hold_age_s = 5;
  PollingLoop loop(&s.page, hold);
  const std::string token = s.server->token();
  const std::string own = "http://127.0.0.1:" + std::to_string(s.server->port());
  // View only: no token, or a wrong one.
  auto none = s.act("resume", {{"nonce", s.nonce()}, {"hold_id", 123456}}, "");
  EXPECT_EQ(none.first, 401);
  EXPECT_EQ(none.second["accepted"], false);
  EXPECT_TRUE(loop.saw(OperatorRefusal::kBadToken)) << "journaled as a refusal";
  std::string wrong = token;
  wrong[0] = wrong[0] == 'a' ? 'b' : 'a';
  EXPECT_EQ(s.act("resume", {{"nonce", s.nonce()}, {"hold_id", 123456}}, wrong).first, 401);
  EXPECT_EQ(s.act("stop", {{"nonce", s.nonce()}}, token.substr(0, 10)).first, 401);
  // Another origin, even with the token (a page elsewhere that learnt it).
  EXPECT_EQ(s.act("resume", {{"nonce", s.nonce()}, {"hold_id", 123456}}, token, "http://evil.example").first, 403);
  EXPECT_TRUE(loop.saw(OperatorRefusal::kOrigin));
  // Malformed bodies.
  for (const nlohmann::json& body : {nlohmann::json{{"hold_id", 123456}}, nlohmann::json{{"nonce", 5}},
                                     nlohmann::json{{"nonce", s.nonce()}, {"hold_id", -1}},
                                     nlohmann::json{{"nonce", s.nonce()}, {"hold_id", 1e12}},
                                     nlohmann::json{{"nonce", s.nonce()}, {"hold_id", "123456"}},
                                     nlohmann::json{{"nonce", s.nonce()}, {"hold_id", 0}}, nlohmann::json::array()})
    EXPECT_EQ(s.act("resume", body, token).first, 400) << body.dump();
  EXPECT_TRUE(loop.saw(OperatorRefusal::kMalformed));
  // A key given twice is ambiguous, whichever value would win (an outside probe found the last
  // one taken): a repeated hold_id and a repeated nonce are refused alike.
  EXPECT_EQ(s.act_text("resume", "{\"nonce\":\"" + s.nonce() + "\",\"hold_id\":1,\"hold_id\":123456}", token).first,
            400);
  EXPECT_EQ(s.act_text("resume", "{\"nonce\":\"" + s.nonce() + "\",\"nonce\":\"" + s.nonce() + "\",\"hold_id\":123456}",
                       token)
                .first,
            400);
  // No HOLD named: the loop refuses it for that.
  auto unnamed = s.act("resume", {{"nonce", s.nonce()}}, token);
  EXPECT_EQ(unnamed.first, 409);
  EXPECT_EQ(unnamed.second["reason"], to_string(OperatorRefusal::kNoHoldId));
  // A nonce never issued.
  EXPECT_EQ(s.act("resume", {{"nonce", std::string(32, 'a')}, {"hold_id", 123456}}, token).first, 409);
  EXPECT_TRUE(loop.saw(OperatorRefusal::kReplayed));
  // Everything right but the HOLD it names: the loop refuses it.
  auto other_hold = s.act("resume", {{"nonce", s.nonce()}, {"hold_id", 654321}}, token, own);
  EXPECT_EQ(other_hold.first, 409);
  EXPECT_EQ(other_hold.second["reason"], to_string(OperatorRefusal::kWrongHold));
  // Everything right: accepted by the loop; the same request again is a replay.
  const nlohmann::json body = {{"nonce", s.nonce()}, {"hold_id", 123456}};
  auto accepted = s.act("resume", body, token, own);
  EXPECT_EQ(accepted.first, 200);
  EXPECT_EQ(accepted.second["accepted"], true);
  auto replayed = s.act("resume", body, token, own);
  EXPECT_EQ(replayed.first, 409);
  EXPECT_EQ(s.server->counters().actions_accepted, 1);
  EXPECT_GE(s.server->counters().requests_refused, 13);
  // A huge body is refused before anything reads it.
  auto huge = s.client().Post("/api/stop", {{"Authorization", "Bearer " + token}}, std::string(1 << 20, 'x'),
                              "application/json");
  ASSERT_TRUE(huge);
  EXPECT_NE(huge->status, 200);
}

// Nonces are the operator's: a client that may only watch gets none, so a flood of requests for
// them cannot push the operator's nonce out of the book (an outside probe's 5,000 requests in half
// a second left 19 of 20 operator actions refused as "nonce used already").
TEST(MonitorServer, AClientWithoutTheTokenGetsNoNonceAndCannotBlockTheOperatorsStop) {
  Served s;
  OperatorView track;
  track.state = TrackingState::kTrack;
  PollingLoop loop(&s.page, track);
  const std::string token = s.server->token();
  std::string wrong = token;
  wrong[0] = wrong[0] == 'a' ? 'b' : 'a';
  EXPECT_EQ(s.client().Get("/api/nonce")->status, 401);
  EXPECT_EQ(s.client().Get("/api/nonce", {{"Authorization", "Bearer " + wrong}})->status, 401);
  const std::string operators = s.nonce();  // the operator takes a nonce, then a watcher floods
  const std::int64_t refused_before = s.server->counters().requests_refused;
  for (int i = 0; i < 4 * NonceBook::kNonces; ++i) {
    auto res = s.client().Get("/api/nonce");
    ASSERT_TRUE(res);
    EXPECT_EQ(res->status, 401);
    EXPECT_EQ(nlohmann::json::parse(res->body).value("nonce", ""), "") << "no nonce without the token";
  }
  EXPECT_EQ(s.server->counters().requests_refused - refused_before, 4 * NonceBook::kNonces);
  auto stop = s.act("stop", {{"nonce", operators}}, token);
  EXPECT_EQ(stop.first, 200) << stop.second.dump();
  EXPECT_EQ(stop.second["accepted"], true);
}

std::string read_events(int port, const std::function<bool(const std::string&)>& done);

// `n` event streams held open on threads of their own until the object goes (the hub is then
// woken so that each stream sees its end at once).
struct OpenStreams {
  Served& served;
  std::atomic<bool> stop{false};
  std::vector<std::thread> threads;
  OpenStreams(Served& s, int n) : served(s) {
    for (int i = 0; i < n; ++i)
      threads.emplace_back([this] {
        read_events(served.server->port(), [this](const std::string&) { return stop.load(); });
      });
    for (int i = 0; i < 5000 && served.server->counters().event_clients < n; ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  ~OpenStreams() {
    stop = true;
    served.hub.publish(record(1, TrackingState::kTrack, TrackingState::kTrack, 0, false));
    for (auto& t : threads) t.join();
  }
};

// A client's socket to the server, its request started and never finished: it trickles a
// header's bytes in, one at a time.
int connect_raw(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port));
  inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
  EXPECT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  return fd;
}

// Issue 50 probe: 16 event streams and 16 clients that trickle their request in (a byte a
// second; no token needed) held every thread of the page, and the operator's nonce and Stop got
// no answer. A request reaches a thread only once it has arrived whole; one that has not within
// 3 s is dropped.
TEST(MonitorServer, ClientsTricklingTheirRequestsHoldNoThreadTheOperatorNeeds) {
  Served s;
  OperatorView track;
  track.state = TrackingState::kTrack;
  PollingLoop loop(&s.page, track);
  OpenStreams streams(s, 16);
  ASSERT_EQ(s.server->counters().event_clients, 16) << "every event stream is open";
  const std::string start = "GET /api/state HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(s.server->port()) +
                            "\r\nX-Slow: ";
  std::vector<int> slow;
  for (int i = 0; i < 48; ++i) {
    slow.push_back(connect_raw(s.server->port()));
    ASSERT_EQ(::send(slow.back(), start.data(), start.size(), MSG_NOSIGNAL), ssize_t(start.size()));
  }
  std::atomic<bool> trickling{true};
  std::thread trickle([&] {
    while (trickling.load()) {
      for (int fd : slow) (void)::send(fd, "a", 1, MSG_NOSIGNAL | MSG_DONTWAIT);
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
  });
  const auto asked = std::chrono::steady_clock::now();
  const std::string nonce = s.nonce();
  auto stop = s.act("stop", {{"nonce", nonce}}, s.server->token());
  EXPECT_EQ(stop.first, 200) << stop.second.dump();
  EXPECT_EQ(stop.second["accepted"], true);
  std::printf("the operator's nonce and stop answered in %.0f ms beside 16 streams and 48 trickling clients\n",
              1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - asked).count());
  // The trickling clients are dropped once their 3 s are up, however they trickle.
  int closed = 0;
  for (int fd : slow) {
    char c;
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 10'000) > 0 && ::recv(fd, &c, 1, 0) <= 0) ++closed;
  }
  EXPECT_EQ(closed, 48) << "every trickling client was dropped";
  trickling = false;
  trickle.join();
  for (int fd : slow) ::close(fd);
}

// The reply the server gives `request` on a connection of its own ("" if none within 5 s).
std::string raw_reply(int port, const std::string& request) {
  const int fd = connect_raw(port);
  (void)::send(fd, request.data(), request.size(), MSG_NOSIGNAL);
  std::string reply;
  char buffer[512];
  pollfd p{fd, POLLIN, 0};
  while (::poll(&p, 1, 5000) > 0) {
    const ssize_t n = ::recv(fd, buffer, sizeof buffer, 0);
    if (n <= 0) break;
    reply.append(buffer, std::size_t(n));
  }
  ::close(fd);
  return reply;
}

// Issue 50, second probe: requests whose body never finishes (a POST without a length, a length
// beyond the limit, headers beyond it, a chunked body) still reached a worker, which waited on
// them, and 32 such clients starved the operator's Stop again. The front answers them itself.
TEST(MonitorServer, RequestsAWorkerWouldWaitOnAreAnsweredByTheFront) {
  Served s;
  const int port = s.server->port();
  const std::string host = "Host: 127.0.0.1:" + std::to_string(port) + "\r\n";
  const std::string big_header = "X-Pad: " + std::string(12000, 'p') + "\r\n";
  const std::vector<std::pair<std::string, std::string>> refused = {
      {"POST /api/stop HTTP/1.1\r\n" + host + "\r\n{", "411"},
      {"POST /api/stop HTTP/1.1\r\n" + host + "Content-Length: 100000000\r\n\r\n{", "413"},
      {"POST /api/stop HTTP/1.1\r\n" + host + big_header + "Content-Length: 4000\r\n\r\n{", "431"},
      {"POST /api/stop HTTP/1.1\r\n" + host + "Transfer-Encoding : chunked\r\n\r\n1\r\n{", "411"},
      {"POST /api/stop HTTP/1.1\r\n" + host + "Content-Length: 2\r\nContent-Length: 3\r\n\r\n{}", "400"},
      {"DELETE /api/stop HTTP/1.1\r\n" + host + "\r\n", "405"},
      {"POST /api/stop HTTP/1.1\r\n" + host + "Content-Length: -1\r\n\r\n{}", "400"},
  };
  for (const auto& [request, status] : refused) {
    const std::string reply = raw_reply(port, request);
    EXPECT_EQ(reply.rfind("HTTP/1.1 " + status, 0), 0u) << request.substr(0, 120) << "\n-> " << reply;
  }
  // 48 clients trickling each kind of body at once, beside 16 event streams: the operator acts.
  OperatorView track;
  track.state = TrackingState::kTrack;
  PollingLoop loop(&s.page, track);
  OpenStreams streams(s, 16);
  std::vector<int> slow;
  for (int i = 0; i < 48; ++i) {
    slow.push_back(connect_raw(port));
    const std::string& start = refused[std::size_t(i) % 2].first;  // no length, or one too long
    (void)::send(slow.back(), start.data(), start.size(), MSG_NOSIGNAL);
  }
  const std::string nonce = s.nonce();
  auto stop = s.act("stop", {{"nonce", nonce}}, s.server->token());
  EXPECT_EQ(stop.first, 200) << stop.second.dump();
  for (int fd : slow) ::close(fd);
}

// Issue 50, third probe: a PRI request and a length hidden behind a bare LF each held a worker for
// its read deadline, and 300 such connections delayed the operator's Stop by 8 s. The front
// refuses both at once; the operator's requests (the run's token) go ahead of strangers' waiting.
TEST(MonitorServer, TheOperatorsRequestsGoAheadOfAStrangersFlood) {
  Served s;
  const int port = s.server->port();
  const std::string host = "Host: 127.0.0.1:" + std::to_string(port);
  EXPECT_EQ(raw_reply(port, "PRI /api/state HTTP/1.1\r\n" + host + "\r\n\r\n").rfind("HTTP/1.1 405", 0), 0u);
  EXPECT_EQ(raw_reply(port, "GET /api/state HTTP/1.1\n" + host + "\n\n").rfind("HTTP/1.1 400", 0), 0u)
      << "bare LF lines: answered, not reset after 3 s";
  EXPECT_EQ(raw_reply(port, "POST /api/stop HTTP/1.1\r\n" + host + "\r\nX: a\nContent-Length: 4000\r\n"
                            "Content-Length: 0\r\n\r\n")
                .rfind("HTTP/1.1 400", 0),
            0u)
      << "a length hidden behind a bare LF";
  OperatorView track;
  track.state = TrackingState::kTrack;
  PollingLoop loop(&s.page, track);
  OpenStreams streams(s, 16);
  const std::string get = "GET /api/state HTTP/1.1\r\n" + host + "\r\n\r\n";
  std::vector<int> flood;
  for (int i = 0; i < 300; ++i) {
    flood.push_back(connect_raw(port));
    (void)::send(flood.back(), get.data(), get.size(), MSG_NOSIGNAL);
  }
  const std::string nonce = s.nonce();
  auto stop = s.act("stop", {{"nonce", nonce}}, s.server->token());
  EXPECT_EQ(stop.first, 200) << stop.second.dump();
  for (int fd : flood) ::close(fd);
}

TEST(MonitorServer, WithoutALoopAnActionIsAnsweredAndWithdrawn) {
  Served s;
  auto answer = s.act("stop", {{"nonce", s.nonce()}}, s.server->token());
  EXPECT_EQ(answer.first, 504);
  OperatorPoll poll;
  s.page.poll(OperatorView{}, &poll);
  EXPECT_EQ(poll.command, OperatorCommand::kNone) << "a stop nobody answered does not act later";
}

// Reads an event stream until `done` says so or 5 s pass; the text received.
std::string read_events(int port, const std::function<bool(const std::string&)>& done) {
  httplib::Client c("127.0.0.1", port);
  c.set_read_timeout(5, 0);
  std::string text;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  c.Get("/api/events", [&](const char* data, std::size_t length) {
    text.append(data, length);
    return !done(text) && std::chrono::steady_clock::now() < deadline;
  });
  return text;
}

TEST(MonitorServer, EventsReachTenClientsWhileAStalledOneDelaysNobody) {
  Served s;
  // A client that asks for the stream and never reads it.
  const int stalled = ::socket(AF_INET, SOCK_STREAM, 0);
  const int small = 1024;
  ::setsockopt(stalled, SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(s.server->port()));
  inet_pton(AF_INET, "127.0.0.1", &addr.sin_addr);
  ASSERT_EQ(::connect(stalled, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  const std::string request = "GET /api/events HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(s.server->port()) + "\r\n\r\n";
  ASSERT_EQ(::send(stalled, request.data(), request.size(), 0), ssize_t(request.size()));
  std::vector<std::thread> clients;
  std::atomic<int> saw_last{0}, saw_images{0};
  for (int i = 0; i < 10; ++i)
    clients.emplace_back([&] {
      const std::string text = read_events(s.server->port(), [](const std::string& t) {
        return t.find("\"cycle\":299") != std::string::npos && t.find("event: images") != std::string::npos;
      });
      if (text.find("\"cycle\":299") != std::string::npos) ++saw_last;
      if (text.find("event: images") != std::string::npos) ++saw_images;
    });
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (s.server->counters().event_clients < 11 && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  EXPECT_EQ(s.server->counters().event_clients, 11) << "ten readers and the stalled one";
  for (std::uint64_t c = 0; c < 300; ++c) {
    s.hub.feed.publish_record(record(c, TrackingState::kTrack, TrackingState::kTrack, 0.01 * double(c), true).record,
                              true);
    if (c % 50 == 0) s.hub.publish_images(std::int64_t(c));
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  for (auto& t : clients) t.join();
  EXPECT_EQ(saw_last.load(), 10) << "every client saw the last cycle";
  EXPECT_EQ(saw_images.load(), 10);
  EXPECT_EQ(s.hub.hub->status().counts.records_dropped, 0u) << "the hub kept up with every record";
  ::close(stalled);
}

TEST(MonitorServer, EventStreamsAreLimited) {
  Served s(2);
  std::atomic<bool> stop{false};
  std::vector<std::thread> open;
  for (int i = 0; i < 2; ++i)
    open.emplace_back([&] { read_events(s.server->port(), [&](const std::string&) { return stop.load(); }); });
  for (int i = 0; i < 5000 && s.server->counters().event_clients < 2; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  EXPECT_EQ(s.server->counters().event_clients, 2) << "both streams are open before the third asks";
  auto third = s.client().Get("/api/events");
  ASSERT_TRUE(third);
  EXPECT_EQ(third->status, 503);
  stop = true;
  s.hub.publish(record(1, TrackingState::kTrack, TrackingState::kTrack, 0, false));  // wakes the streams
  for (auto& t : open) t.join();
}

TEST(MonitorServer, RefusesBadSettingsAndABusyPort) {
  Served s;
  MonitorOptions o;
  o.token_dir = s.dir.path();
  o.listen = {"127.0.0.1", s.server->port()};
  EXPECT_FALSE(MonitorServer::start(s.hub.hub.get(), &s.page, o).ok()) << "the port is taken";
  o.listen.port = 0;
  for (double rate : {0.0, -1.0, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(), 1e12}) {
    MonitorOptions bad = o;
    bad.event_rate_hz = rate;
    EXPECT_FALSE(MonitorServer::start(s.hub.hub.get(), &s.page, bad).ok()) << rate;
  }
  for (const char* bad : {"javascript:alert(1)", "http://console", "http://console:99999", "http://console:0",
                          "http://console:8o", "http://:8080", "http://console:8080/page", "https://console:8080"}) {
    MonitorOptions origin = o;
    origin.extra_origins = {bad};
    EXPECT_FALSE(check_monitor_origins(origin).ok()) << bad;
    EXPECT_FALSE(MonitorServer::start(s.hub.hub.get(), &s.page, origin).ok()) << bad;
  }
  MonitorOptions console = o;
  console.extra_origins = {"http://console.room:8080"};
  EXPECT_TRUE(check_monitor_origins(console).ok());
  // Every interface: a browser's Host is the name it used, which the server must be told.
  MonitorOptions every = o;
  every.listen = {"0.0.0.0", 0};
  EXPECT_FALSE(check_monitor_origins(every).ok());
  every.extra_origins = console.extra_origins;
  EXPECT_TRUE(check_monitor_origins(every).ok());
  EXPECT_FALSE(MonitorServer::start(nullptr, &s.page, o).ok());
}

}  // namespace
}  // namespace lftrack::watch
