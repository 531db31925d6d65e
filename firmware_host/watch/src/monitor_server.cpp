#include "lftrack/watch/monitor_server.hpp"

#include <httplib.h>
#include <sys/socket.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <set>
#include <string_view>

#include "lftrack/loop/allocation_counter.hpp"
#include "lftrack/loop/realtime_setup.hpp"
#include "fronted_server.hpp"
#include "monitor_assets.hpp"
#include "monitor_json.hpp"

namespace lftrack::watch {

using loop::exclude_this_thread_from_allocation_count;
using loop::make_current_thread_best_effort;
using loop::OperatorCommand;
using loop::OperatorRefusal;
using loop::OperatorRequest;
namespace {

constexpr const char* kJson = "application/json";

// cpp-httplib's task queue, with threads that run at best effort (never above the cycle) and
// whose allocations are not the cycle's (allocation_counter.hpp).
class WatcherTaskQueue final : public WorkerQueue {
 public:
  explicit WatcherTaskQueue(std::size_t threads) {
    for (std::size_t i = 0; i < threads; ++i) workers_.emplace_back([this] { work(); });
  }
  ~WatcherTaskQueue() override { shutdown(); }
  void enqueue(std::function<void()> job) override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      jobs_.push_back(std::move(job));
    }
    wake_.notify_one();
  }
  void enqueue_first(std::function<void()> job) override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      jobs_.push_front(std::move(job));
    }
    wake_.notify_one();
  }
  void shutdown() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    wake_.notify_all();
    for (std::thread& t : workers_)
      if (t.joinable()) t.join();
  }

 private:
  void work() {
    make_current_thread_best_effort();
    exclude_this_thread_from_allocation_count();
    for (;;) {
      std::function<void()> job;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        wake_.wait(lock, [&] { return stop_ || !jobs_.empty(); });
        if (jobs_.empty()) return;  // stopping, nothing left
        job = std::move(jobs_.front());
        jobs_.pop_front();
      }
      job();
    }
  }
  std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::function<void()>> jobs_;
  std::vector<std::thread> workers_;
  bool stop_ = false;
};

void reply(httplib::Response& res, int status, const nlohmann::json& body) {
  res.status = status;
  res.set_content(body.dump(), kJson);
}

// "resume", "stop" or "reset" as the loop's command.
OperatorCommand action_command(const std::string& path) {
  if (path == "/api/resume") return OperatorCommand::kResume;
  if (path == "/api/reset") return OperatorCommand::kReset;
  return OperatorCommand::kStop;
}

// The body of an action: {"nonce": a string, "hold_id": 1..4294967295}; hold_id may be left out
// (the loop then refuses a resume or reset for not naming its HOLD, or for coming outside one).
// False when it is anything else.
bool parse_action(const std::string& body, OperatorCommand command, std::string* nonce, OperatorRequest* request) {
  // A key given twice is refused, not read as its last value: a safety command is unambiguous.
  std::set<std::string> top_level_keys;
  bool repeated_key = false;
  const auto note_keys = [&](int depth, nlohmann::json::parse_event_t event, nlohmann::json& parsed) {
    if (event == nlohmann::json::parse_event_t::key && depth == 1 &&
        !top_level_keys.insert(parsed.get<std::string>()).second)
      repeated_key = true;
    return true;
  };
  const auto j = nlohmann::json::parse(body, note_keys, /*allow_exceptions=*/false);
  if (repeated_key) return false;
  if (!j.is_object() || !j.contains("nonce") || !j["nonce"].is_string()) return false;
  *nonce = j["nonce"].get<std::string>();
  *request = {};
  request->command = command;
  if (!j.contains("hold_id")) return true;
  if (!j["hold_id"].is_number_unsigned()) return false;
  const auto id = j["hold_id"].get<std::uint64_t>();
  if (id == 0 || id > 0xFFFFFFFFull) return false;
  request->names_hold = true;
  request->hold_id = static_cast<std::uint32_t>(id);
  return true;
}

}  // namespace

Status check_monitor_origins(const MonitorOptions& options) {
  for (const std::string& origin : options.extra_origins) {
    const std::size_t colon = origin.rfind(':');
    const bool form = origin.rfind("http://", 0) == 0 && origin.size() > 7 && origin.find('/', 7) == std::string::npos &&
                      colon != std::string::npos && colon > 7 && colon + 1 < origin.size() &&
                      origin.find_first_not_of("0123456789", colon + 1) == std::string::npos;
    const long port = form && origin.size() - colon - 1 <= 5 ? std::stol(origin.substr(colon + 1)) : 0;
    if (!form || port < 1 || port > 65535)
      return invalid_argument("monitor: origin '" + origin + "' is not of the form http://HOST:PORT (port 1 to 65535)");
  }
  if (options.listen.wildcard() && options.extra_origins.empty())
    return invalid_argument("monitor: listening on every interface (" + options.listen.text() +
                            "), a browser's Host is the name it used; give it with --monitor-origin "
                            "http://HOST:PORT, or listen on the one address the console uses");
  return {};
}

Result<std::unique_ptr<MonitorServer>> MonitorServer::start(CycleHub* hub, PageOperator* page,
                                                            const MonitorOptions& options) {
  if (hub == nullptr || page == nullptr) return invalid_argument("monitor: needs the cycle hub and the page operator");
  LFTRACK_RETURN_IF_ERROR(check_monitor_origins(options));
  if (options.max_event_clients < 1 || options.max_event_clients > 256)
    return invalid_argument("monitor: the event clients must be 1 to 256");
  if (!(std::isfinite(options.event_rate_hz) && options.event_rate_hz > 0 && options.event_rate_hz <= 1000))
    return invalid_argument("monitor: the event rate must be above 0 and at most 1000 Hz");
  if (options.action_wait.count() < 10 || options.action_wait.count() > 60000)
    return invalid_argument("monitor: the action wait must be 10 ms to 60 s");
  auto token = random_hex(32);
  if (!token.ok()) return token.status();
  std::unique_ptr<MonitorServer> s(new MonitorServer);
  s->hub_ = hub;
  s->page_ = page;
  s->options_ = options;
  s->token_ = *token;
  // Every event stream holds a thread; the rest serve the page, state and actions. A connection
  // gets a thread only once its request has arrived whole (fronted_server.hpp: a client trickling
  // its request in held a thread for ever, and 32 of them starved the operator's Stop), and serves
  // one request: an idle keep-alive connection would hold a thread for nothing while others wait.
  const std::size_t threads = std::size_t(options.max_event_clients) + 16;
  FrontedServer::Limits limits;
  limits.read_timeout_ms = 2000;
  limits.write_timeout_ms = 2000;  // a client that stops reading loses its stream, nothing else
  // The operator's requests (the run's token in Authorization) go ahead of strangers' (second
  // outside probe: 300 view-only connections delayed the operator's Stop by 8 s).
  limits.urgent = [token = *token](std::string_view head) {
    bool operators = false;
    for_each_header(head, [&](const std::string& name, std::string_view value) {
      if (name != "authorization") return true;
      const std::string_view bearer = "Bearer ";
      operators = value.substr(0, bearer.size()) == bearer && token_matches(token, std::string(value.substr(bearer.size())));
      return false;
    });
    return operators;
  };
  s->server_ = std::make_unique<FrontedServer>(limits, [threads] { return new WatcherTaskQueue(threads); });
  httplib::Server& svr = *s->server_;
  svr.set_payload_max_length(4096);
  svr.set_keep_alive_max_count(1);
  svr.set_keep_alive_timeout(1);
  // cpp-httplib's default sets SO_REUSEPORT, which lets a second server (another lftrack) bind the
  // same port and take half the connections. Only SO_REUSEADDR: a restart may rebind a port in
  // TIME_WAIT, and a port another server listens on is refused.
  svr.set_socket_options([](int sock) {
    const int yes = 1;
    ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
  });
  svr.set_default_headers({{"X-Frame-Options", "DENY"},
                           {"Content-Security-Policy",
                            "default-src 'self'; img-src 'self' data:; connect-src 'self'; frame-ancestors 'none'"},
                           {"X-Content-Type-Options", "nosniff"},
                           {"Referrer-Policy", "no-referrer"},
                           {"Cache-Control", "no-store"}});
  s->add_routes();
  const ListenAddress& at = options.listen;
  s->port_ = at.port == 0 ? svr.bind_to_any_port(at.address) : (svr.bind_to_port(at.address, at.port) ? at.port : -1);
  if (s->port_ <= 0) return io_error("monitor: cannot listen on " + at.text() + " (in use, or not this host's address)");
  const std::string port = std::to_string(s->port_);
  s->hosts_.push_back(at.address + ":" + port);
  if (at.loopback()) s->hosts_.push_back("localhost:" + port);
  for (const std::string& origin : options.extra_origins) s->hosts_.push_back(origin.substr(7));
  for (const std::string& host : s->hosts_) s->origins_.push_back("http://" + host);
  std::filesystem::path file = options.token_file;
  if (file.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(options.token_dir, ec);
    file = options.token_dir / ("monitor-" + at.address + "-" + port + ".token");
  }
  auto written = TokenFile::write(file, s->token_);
  if (!written.ok()) return written.status().with_context("monitor token");
  s->token_file_ = std::move(written).value();
  s->thread_ = std::thread([server = s->server_.get()] {
    make_current_thread_best_effort();  // never above the cycle
    exclude_this_thread_from_allocation_count();
    server->serve();
  });
  // Serving before start() returns, so that stop() (the destructor) always finds it running.
  for (int waited_ms = 0; !s->server_->serving(); ++waited_ms) {
    if (waited_ms > 10000) return internal_error("monitor: the HTTP server did not start");
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  return s;
}

MonitorServer::~MonitorServer() {
  stopping_.store(true);
  if (server_) server_->stop_serving();
  if (thread_.joinable()) thread_.join();
}

std::string MonitorServer::url() const { return "http://" + hosts_.front() + "/"; }

MonitorCounters MonitorServer::counters() const {
  return {event_clients_.load(), refused_.load(), accepted_.load()};
}

const char* MonitorServer::token_refusal(const httplib::Request& req) const {
  const std::string auth = req.get_header_value("Authorization");
  const std::string bearer = "Bearer ";
  const std::string offered = auth.rfind(bearer, 0) == 0 ? auth.substr(bearer.size()) : std::string();
  if (token_matches(token_, offered)) return nullptr;
  return offered.empty() ? "view only: no operator token" : "wrong operator token";
}

bool MonitorServer::host_allowed(const std::string& host) const {
  return std::find(hosts_.begin(), hosts_.end(), host) != hosts_.end();
}

bool MonitorServer::origin_allowed(const std::string& origin) const {
  return std::find(origins_.begin(), origins_.end(), origin) != origins_.end();
}

void MonitorServer::add_routes() {
  httplib::Server& svr = *server_;
  svr.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    if (host_allowed(req.get_header_value("Host"))) return httplib::Server::HandlerResponse::Unhandled;
    ++refused_;
    if (req.method == "POST") page_->refused_before_loop(OperatorRefusal::kOrigin);
    reply(res, 403, {{"error", "this server does not answer for host '" + req.get_header_value("Host") + "'"}});
    return httplib::Server::HandlerResponse::Handled;
  });
  svr.Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_content(monitor_page_html(), "text/html; charset=utf-8");
  });
  svr.Get("/monitor.js", [](const httplib::Request&, httplib::Response& res) {
    res.set_content(monitor_page_js(), "text/javascript; charset=utf-8");
  });
  svr.Get("/monitor.css", [](const httplib::Request&, httplib::Response& res) {
    res.set_content(monitor_page_css(), "text/css; charset=utf-8");
  });
  svr.Get("/api/state", [this](const httplib::Request&, httplib::Response& res) {
    reply(res, 200, state_json(hub_->status(), hub_->options()));
  });
  // Nonces are the operator's: only a request with the token gets one, so a client that may only
  // watch cannot push the operator's nonce out of the book (an outside probe took 5,000 in half
  // a second and 19 of 20 operator actions were refused). Not an action: counted, not journaled.
  svr.Get("/api/nonce", [this](const httplib::Request& req, httplib::Response& res) {
    if (const char* refusal = token_refusal(req)) {
      ++refused_;
      return reply(res, 401, {{"accepted", false}, {"reason", refusal}});
    }
    auto nonce = nonces_.issue();
    if (!nonce.ok()) return reply(res, 500, {{"error", nonce.status().message()}});
    reply(res, 200, {{"nonce", *nonce}, {"lifetime_s", NonceBook::kNonceLifetime.count()}});
  });
  svr.Post(R"(/api/(resume|stop|reset))", [this](const httplib::Request& req, httplib::Response& res) {
    auto refuse = [&](int status, OperatorRefusal why, const std::string& message) {
      ++refused_;
      page_->refused_before_loop(why);
      reply(res, status, {{"accepted", false}, {"reason", message}});
    };
    const std::string origin = req.get_header_value("Origin");
    if (!origin.empty() && !origin_allowed(origin))
      return refuse(403, OperatorRefusal::kOrigin, "a page from " + origin + " may not act here");
    if (const char* refusal = token_refusal(req)) return refuse(401, OperatorRefusal::kBadToken, refusal);
    std::string nonce;
    OperatorRequest request;
    const OperatorCommand command = action_command(req.path);
    if (!parse_action(req.body, command, &nonce, &request))
      return refuse(400, OperatorRefusal::kMalformed, "expected {\"nonce\": ..., \"hold_id\": the HOLD's id}");
    if (!nonces_.spend(nonce))
      return refuse(409, OperatorRefusal::kReplayed, "the nonce was used already, is too old or was never issued");
    const PageOperator::Verdict v = page_->submit(request, options_.action_wait);
    using Outcome = PageOperator::Verdict::Outcome;
    switch (v.outcome) {
      case Outcome::kAccepted:
        ++accepted_;
        return reply(res, 200, {{"accepted", true}, {"command", to_string(command)}});
      case Outcome::kRefused:
        return reply(res, 409, {{"accepted", false}, {"reason", to_string(v.refusal)}});
      case Outcome::kBusy:
        return reply(res, 503, {{"accepted", false}, {"reason", "too many actions waiting for the loop"}});
      case Outcome::kNoAnswer:
        break;
    }
    reply(res, 504, {{"accepted", false}, {"reason", "the loop did not answer (is it still running?)"}});
  });
  svr.Get("/api/events", [this](const httplib::Request&, httplib::Response& res) {
    if (event_clients_.fetch_add(1) >= options_.max_event_clients) {
      --event_clients_;
      return reply(res, 503, {{"error", "too many event streams open"}});
    }
    struct Stream {
      std::uint64_t seq = ~std::uint64_t{0}, images = 0;
      std::int64_t last_cycle = -1;
      std::chrono::steady_clock::time_point last_sent{}, last_write = std::chrono::steady_clock::now();
    };
    auto stream = std::make_shared<Stream>();
    const auto min_gap = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
        std::chrono::duration<double>(1.0 / options_.event_rate_hz));
    res.set_header("X-Accel-Buffering", "no");
    res.set_chunked_content_provider(
        "text/event-stream",
        [this, stream, min_gap](std::size_t, httplib::DataSink& sink) {
          if (stopping_.load() || hub_->stopped()) return false;
          std::this_thread::sleep_until(stream->last_sent + min_gap);  // at most event_rate_hz
          const bool news = hub_->wait_for_news(stream->seq, stream->images, std::chrono::milliseconds(250));
          std::string text;
          if (news) {
            const HubStatus status = hub_->status();
            if (status.seq != stream->seq) {
              const auto trace = hub_->trace_after(stream->last_cycle, std::size_t(hub_->options().trace_cycles));
              if (!trace.empty()) stream->last_cycle = trace.back().cycle;
              nlohmann::json event = {{"state", state_json(status, hub_->options())}, {"trace", trace_json(trace)}};
              text += "event: state\ndata: " + event.dump() + "\n\n";
              stream->seq = status.seq;
            }
            if (status.images_seq != stream->images) {
              if (auto images = hub_->images()) text += "event: images\ndata: " + images_json(*images).dump() + "\n\n";
              stream->images = status.images_seq;
            }
          }
          const auto now = std::chrono::steady_clock::now();
          if (text.empty() && now - stream->last_write > std::chrono::seconds(10)) text = ": keep-alive\n\n";
          if (text.empty()) return true;
          stream->last_sent = now;
          stream->last_write = now;
          return sink.write(text.data(), text.size());
        },
        [this](bool) { --event_clients_; });
  });
}

}  // namespace lftrack::watch
