#pragma once
// The operator's live view (`lftrack sim|run|replay --monitor [ADDRESS:]PORT`): an embedded HTTP
// server (cpp-httplib, from Debian: one header's API over a compiled library, a thread per
// connection from a pool, nothing else to run; CivetWeb's C API and Boost.Beast's asynchronous
// machinery are more than a page and a few endpoints need) serving
//   GET  /                 the page (monitor.html, monitor.js, monitor.css, compiled in)
//   GET  /api/state        the current snapshot as JSON (monitor_json.hpp)
//   GET  /api/events       server-sent events: "state" with the new trace rows at most
//                          event_rate_hz, "images" when new display images are ready
//   GET  /api/nonce        a single-use nonce for one action (operator_token.hpp); the token's
//                          holder's only: header "Authorization: Bearer TOKEN" 
//   POST /api/resume|stop|reset   an operator action: header "Authorization: Bearer TOKEN",
//                          body {"nonce": "...", "hold_id": N} (hold_id for resume and reset)
// Everything reads the cycle hub; nothing here touches the loop, which never waits for a page.
//
// Who may act: the run's token, compared in constant time; a nonce spent once, within 30 s; and,
// from a browser, the page's own origin. Refusals answer 401 (token), 409 (nonce), 403 (origin
// or host) or 400 (malformed), and each is journaled by the loop as an operator refusal
// (page_operator.hpp). Every request must name an allowed host (the Host header): the listening
// address, or localhost on loopback, or an --monitor-origin; a page another site serves cannot
// read or act through DNS rebinding. Frames are refused (X-Frame-Options, CSP frame-ancestors).

#include <atomic>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/watch/cycle_hub.hpp"
#include "lftrack/watch/listen_address.hpp"
#include "lftrack/watch/operator_token.hpp"
#include "lftrack/watch/page_operator.hpp"

namespace httplib {
class Server;
struct Request;
}

namespace lftrack::watch {
class FrontedServer;

struct MonitorOptions {
  ListenAddress listen;
  // More origins a page may act from ("http://host:port"), e.g. a console's name when listening
  // on every interface.
  std::vector<std::string> extra_origins;
  // The token's file (mode 0600); empty: <token_dir>/monitor-ADDRESS-PORT.token.
  std::filesystem::path token_file;
  std::filesystem::path token_dir = "out";
  int max_event_clients = 16;  // more are answered 503
  double event_rate_hz = 30;   // state events at most this often per client
  std::chrono::milliseconds action_wait{3000};  // how long an action waits for the loop's verdict
};

struct MonitorCounters {
  std::int64_t event_clients = 0;  // connected now
  std::int64_t requests_refused = 0;  // by host, origin, token, nonce or form
  std::int64_t actions_accepted = 0;
};

// The options' origins, before anything listens: each of the form http://HOST:PORT with a port of
// 1 to 65535; listening on every interface (0.0.0.0) needs at least one, the name the console
// reaches the page by (a browser sends that name as Host, which is checked).
Status check_monitor_origins(const MonitorOptions& options);

class MonitorServer {
 public:
  // Listens, writes the token file and serves on threads of its own. `hub` and `page` must
  // outlive the server.
  static Result<std::unique_ptr<MonitorServer>> start(CycleHub* hub, PageOperator* page,
                                                      const MonitorOptions& options);
  ~MonitorServer();  // stops serving, removes the token file

  int port() const { return port_; }
  std::string url() const;  // http://ADDRESS:PORT/
  const std::string& token() const { return token_; }
  const std::filesystem::path& token_file() const { return token_file_->path(); }
  MonitorCounters counters() const;

 private:
  MonitorServer() = default;
  void add_routes();
  bool host_allowed(const std::string& host) const;
  // Why `req` may not act (no token, or a wrong one: "Authorization: Bearer TOKEN"); null when its
  // token is the run's, compared in constant time.
  const char* token_refusal(const httplib::Request& req) const;
  bool origin_allowed(const std::string& origin) const;

  CycleHub* hub_ = nullptr;
  PageOperator* page_ = nullptr;
  MonitorOptions options_;
  int port_ = 0;
  std::string token_;
  std::unique_ptr<TokenFile> token_file_;
  NonceBook nonces_;
  std::vector<std::string> hosts_;    // allowed Host header values
  std::vector<std::string> origins_;  // allowed Origin header values
  std::unique_ptr<FrontedServer> server_;
  std::thread thread_;
  std::atomic<std::int64_t> event_clients_{0}, refused_{0}, accepted_{0};
  std::atomic<bool> stopping_{false};
};

}  // namespace lftrack::watch
