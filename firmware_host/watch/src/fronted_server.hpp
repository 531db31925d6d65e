#pragma once
// An httplib::Server whose connections reach a worker thread only once their request has arrived
// whole (private to lftrack::watch).
//
// cpp-httplib gives each accepted connection a worker thread, which then reads the request with a
// timeout per read: a client sending a byte a second holds that thread for as long as it likes,
// and a few dozen such clients (no token needed) held every thread, so the operator's Stop got no
// answer (issue 50 probe). Here one front thread accepts and waits on every connection with epoll,
// peeking until the request line, headers and body (exactly Content-Length bytes, at most the
// body limit) are all in the socket's buffer; only then is the connection handed to a worker,
// which reads and answers it at once, and reads nothing after worker_read_deadline_ms. What a
// worker would have to wait on, or could read otherwise than the front, is answered by the front
// and closed: a head beyond its limit (431), a method other than GET, HEAD and POST (405), a line
// not ended by CR LF (400: the front and cpp-httplib would split it differently), a chunked body
// or a POST without a length (411), a bad length (400), a body beyond the limit (413). A request that has not arrived within `arrival_deadline` is dropped, and when
// `max_waiting` connections are arriving the oldest is dropped for a new one: slow clients cost a
// file descriptor each, never a worker.
//
// Workers are then held only by complete requests (answered in microseconds) and by the event
// streams the monitor caps. Call bind_to_port() or bind_to_any_port() first, then serve() on the
// server's own thread; stop_serving() (any thread) ends it.

#include <httplib.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <string_view>

namespace lftrack::watch {

// The workers a FrontedServer hands whole requests to. A request the server's `urgent` test
// picks (the operator's: it carries the run's token) goes ahead of every request waiting, so
// however many strangers queue, the operator's Stop waits only for a worker to come free.
class WorkerQueue : public httplib::TaskQueue {
 public:
  virtual void enqueue_first(std::function<void()> job) = 0;
};

// Calls `each(name, value)` for each header of a request head (the request line, then lines ended
// by CR LF), the name lowercased and the value without surrounding blanks, until `each` returns
// false. The front's reading of a head, and the monitor's of its token, are this one.
void for_each_header(std::string_view head, const std::function<bool(const std::string& name, std::string_view value)>& each);

class FrontedServer final : public httplib::Server {
 public:
  struct Limits {
    std::size_t max_waiting = 256;                      // connections whose request is arriving
    std::chrono::milliseconds arrival_deadline{3000};   // for the whole request, from its accept
    std::size_t max_head_bytes = 8192;                  // request line and headers; beyond: 431
    std::size_t max_body_bytes = 4096;                  // Content-Length; beyond: 413
    int read_timeout_ms = 2000, write_timeout_ms = 2000;  // a worker's socket reads and writes
    int worker_read_deadline_ms = 500;                  // a worker reads nothing after this
    // Given a whole request's head (request line and headers), whether it goes first.
    std::function<bool(std::string_view head)> urgent;
  };
  FrontedServer(const Limits& limits, std::function<WorkerQueue*()> make_workers);
  ~FrontedServer() override;

  // Accepts and watches connections until stop_serving(); false if there was no bound socket.
  bool serve();
  void stop_serving();
  bool serving() const { return serving_.load(); }
  std::uint64_t dropped() const { return dropped_.load(); }  // requests that never arrived whole

 private:
  // httplib's hook for one accepted connection, here a connection whose request has arrived.
  bool process_and_close_socket(socket_t sock) override;

  Limits limits_;
  std::function<WorkerQueue*()> make_workers_;
  std::atomic<bool> serving_{false}, stop_{false};
  std::atomic<std::uint64_t> dropped_{0};
};

}  // namespace lftrack::watch
