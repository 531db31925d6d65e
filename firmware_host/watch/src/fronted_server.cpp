// The monitor's HTTP front (fronted_server.hpp): requests reach a worker only once they are whole.

#include "fronted_server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <map>
#include <string>
#include <string_view>
#include <vector>

namespace lftrack::watch {
namespace {

using Clock = std::chrono::steady_clock;

// A worker's view of a connection whose request is already in the socket's buffer: reads and
// writes with cpp-httplib's per-call timeouts, a small read buffer (the request-line reader asks
// for one byte at a time), writes that never raise SIGPIPE.
class SocketStream final : public httplib::Stream {
 public:
  SocketStream(int fd, int read_timeout_ms, int write_timeout_ms, Clock::time_point read_deadline)
      : fd_(fd), read_ms_(read_timeout_ms), write_ms_(write_timeout_ms), read_deadline_(read_deadline) {}

  // Reads end at the deadline, whatever the per-read timeout: the request was whole when the
  // worker got it, so a worker never waits on a client (belt and braces for the front's checks).
  bool is_readable() const override {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(read_deadline_ - Clock::now()).count();
    return left > 0 && wait(POLLIN, int(std::min<long long>(left, read_ms_)));
  }
  bool is_writable() const override {
    if (!wait(POLLOUT, write_ms_)) return false;
    char c;
    const ssize_t n = ::recv(fd_, &c, 1, MSG_PEEK | MSG_DONTWAIT);
    return n != 0;  // 0: the client has gone (an event stream ends)
  }
  ssize_t read(char* out, size_t size) override {
    if (have_ == used_) {
      if (!is_readable()) return -1;
      const ssize_t n = ::recv(fd_, buffer_, sizeof buffer_, 0);
      if (n <= 0) return n;
      have_ = std::size_t(n);
      used_ = 0;
    }
    const std::size_t n = std::min(size, have_ - used_);
    std::memcpy(out, buffer_ + used_, n);
    used_ += n;
    return ssize_t(n);
  }
  ssize_t write(const char* data, size_t size) override {
    if (!is_writable()) return -1;
    for (;;) {
      const ssize_t n = ::send(fd_, data, size, MSG_NOSIGNAL);
      if (n < 0 && errno == EINTR) continue;
      return n;
    }
  }
  void get_remote_ip_and_port(std::string& ip, int& port) const override { address_of(true, ip, port); }
  void get_local_ip_and_port(std::string& ip, int& port) const override { address_of(false, ip, port); }
  socket_t socket() const override { return fd_; }

 private:
  bool wait(short what, int timeout_ms) const {
    pollfd p{fd_, what, 0};
    for (;;) {
      const int r = ::poll(&p, 1, timeout_ms);
      if (r < 0 && errno == EINTR) continue;
      return r > 0 && (p.revents & what) != 0;
    }
  }
  void address_of(bool peer, std::string& ip, int& port) const {
    sockaddr_storage a{};
    socklen_t length = sizeof a;
    ip.clear();
    port = 0;
    const int r = peer ? ::getpeername(fd_, reinterpret_cast<sockaddr*>(&a), &length)
                       : ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &length);
    if (r != 0) return;
    char text[INET6_ADDRSTRLEN] = {};
    if (a.ss_family == AF_INET) {
      const auto* v4 = reinterpret_cast<const sockaddr_in*>(&a);
      ::inet_ntop(AF_INET, &v4->sin_addr, text, sizeof text);
      port = ntohs(v4->sin_port);
    } else if (a.ss_family == AF_INET6) {
      const auto* v6 = reinterpret_cast<const sockaddr_in6*>(&a);
      ::inet_ntop(AF_INET6, &v6->sin6_addr, text, sizeof text);
      port = ntohs(v6->sin6_port);
    }
    ip = text;
  }

  int fd_;
  int read_ms_, write_ms_;
  Clock::time_point read_deadline_;
  char buffer_[4096];
  std::size_t have_ = 0, used_ = 0;
};

// What the front makes of a connection's bytes so far: still arriving, whole (to a worker), or
// answered here and closed with `status` (0: closed without an answer).
struct Arrival {
  enum Kind { kWaiting, kWhole, kRefuse } kind = kWaiting;
  int status = 0;
  std::size_t head_bytes = 0;  // kWhole: the request line and headers, with the blank line
};

std::string_view trimmed(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

// Whether the request waiting on `fd` has arrived whole: the headers' blank line, then exactly as
// many body bytes as Content-Length says. Refused here, never handed to a worker to wait on (issue
// 50 probe: each such request held a worker for as long as its sender trickled): a request whose
// head outgrows the limit (431), a body in chunks (411), a POST, PUT or PATCH without a length
// (411), a length that is not a number or two that differ (400), a body beyond the limit (413).
Arrival arrival(int fd, std::vector<char>* peek, std::size_t max_head_bytes, std::size_t max_body_bytes) {
  const ssize_t n = ::recv(fd, peek->data(), peek->size(), MSG_PEEK | MSG_DONTWAIT);
  if (n == 0) return {Arrival::kRefuse, 0};
  if (n < 0)
    return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR ? Arrival{} : Arrival{Arrival::kRefuse, 0};
  const std::string_view text(peek->data(), std::size_t(n));
  const std::size_t end = text.find("\r\n\r\n");
  // A line ended by a bare LF, seen as soon as it arrives: a request whose lines all end so
  // would otherwise wait for a blank CR LF line that never comes (third probe: reset at 3 s).
  const std::string_view scanned = end == std::string_view::npos ? text : text.substr(0, end);
  for (std::size_t i = 0; i < scanned.size(); ++i)
    if (scanned[i] == '\n' && (i == 0 || scanned[i - 1] != '\r')) return {Arrival::kRefuse, 400};
  if (end == std::string_view::npos)
    return std::size_t(n) >= max_head_bytes ? Arrival{Arrival::kRefuse, 431} : Arrival{};
  if (end + 4 > max_head_bytes) return {Arrival::kRefuse, 431};
  const std::string_view head = text.substr(0, end);
  // Every line ends in CR LF, and nowhere else is there a CR or LF (bare LFs were refused above):
  // a bare CR or LF splits a line for cpp-httplib that this reader would take as one (second
  // probe: a length hidden that way made a worker wait for a body).
  for (std::size_t i = 0; i < head.size(); ++i)
    if (head[i] == '\r' && (i + 1 >= head.size() || head[i + 1] != '\n')) return {Arrival::kRefuse, 400};
  const std::string method(head.substr(0, head.find(' ')));
  if (method != "GET" && method != "HEAD" && method != "POST") return {Arrival::kRefuse, 405};
  bool has_length = false;
  unsigned long long length = 0;
  int refused = 0;
  for_each_header(head, [&](const std::string& name, std::string_view value) {
    if (name == "transfer-encoding") refused = 411;
    if (name != "content-length") return refused == 0;
    if (value.empty() || value.size() > 19 || value.find_first_not_of("0123456789") != std::string_view::npos) {
      refused = 400;
      return false;
    }
    const unsigned long long this_length = std::strtoull(std::string(value).c_str(), nullptr, 10);
    if (has_length && this_length != length) refused = 400;
    has_length = true;
    length = this_length;
    return refused == 0;
  });
  if (refused != 0) return {Arrival::kRefuse, refused};
  if (!has_length && (method == "POST" || method == "PUT" || method == "PATCH")) return {Arrival::kRefuse, 411};
  if (length > max_body_bytes) return {Arrival::kRefuse, 413};
  return std::size_t(n) >= end + 4 + std::size_t(length) ? Arrival{Arrival::kWhole, 0, end + 4} : Arrival{};
}

// The front's own answer to a refused request, sent without waiting (the socket is non-blocking),
// then the sending side shut: the client reads the answer, then the end of the stream.
void answer(int fd, int status) {
  const char* reason = status == 400   ? "Bad Request"
                       : status == 405 ? "Method Not Allowed"
                       : status == 411 ? "Length Required"
                       : status == 413 ? "Payload Too Large"
                                       : "Request Header Fields Too Large";
  const std::string reply = "HTTP/1.1 " + std::to_string(status) + " " + reason +
                            "\r\nContent-Length: 0\r\nConnection: close\r\n\r\n";
  (void)::send(fd, reply.data(), reply.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
  ::shutdown(fd, SHUT_WR);
}

// Reads and discards what the client still sends; false once it has closed (or failed).
bool drain(int fd) {
  char sink[16384];
  for (int i = 0; i < 64; ++i) {
    const ssize_t n = ::recv(fd, sink, sizeof sink, MSG_DONTWAIT);
    if (n == 0) return false;
    if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
  }
  return true;
}

}  // namespace

void for_each_header(std::string_view head,
                     const std::function<bool(const std::string& name, std::string_view value)>& each) {
  for (std::size_t at = head.find("\r\n"); at != std::string_view::npos && at + 2 < head.size();) {
    const std::size_t next = head.find("\r\n", at + 2);
    const std::string_view line = head.substr(at + 2, next == std::string_view::npos ? std::string_view::npos : next - at - 2);
    at = next;
    const std::size_t colon = line.find(':');
    if (colon == std::string_view::npos) continue;
    std::string name(trimmed(line.substr(0, colon)));
    std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    if (!each(name, trimmed(line.substr(colon + 1)))) return;
  }
}

FrontedServer::FrontedServer(const Limits& limits, std::function<WorkerQueue*()> make_workers)
    : limits_(limits), make_workers_(std::move(make_workers)) {}

FrontedServer::~FrontedServer() {
  stop_serving();
}

void FrontedServer::stop_serving() {
  stop_.store(true);
}

bool FrontedServer::serve() {
  const int listen_fd = svr_sock_.load();
  if (listen_fd < 0) return false;
  std::unique_ptr<WorkerQueue> workers(make_workers_());
  const int ep = ::epoll_create1(EPOLL_CLOEXEC);
  if (ep < 0) return false;
  ::fcntl(listen_fd, F_SETFL, ::fcntl(listen_fd, F_GETFL) | O_NONBLOCK);
  epoll_event listen_event{};
  listen_event.events = EPOLLIN;
  listen_event.data.fd = listen_fd;
  ::epoll_ctl(ep, EPOLL_CTL_ADD, listen_fd, &listen_event);
  std::map<int, Clock::time_point> arriving;  // fd -> accepted at
  // Refused with an answer: what the client still sends (a body it was told is too large) is read
  // and discarded for a second before the close, so that the close does not reset the connection
  // and take the answer with it ("lingering close").
  std::map<int, Clock::time_point> closing;  // fd -> close by
  std::vector<char> peek(limits_.max_head_bytes + limits_.max_body_bytes + 1);
  const auto close_now = [&](int fd) {
    ::epoll_ctl(ep, EPOLL_CTL_DEL, fd, nullptr);
    ::close(fd);
    arriving.erase(fd);
    closing.erase(fd);
  };
  const auto drop = [&](int fd, int status = 0) {
    dropped_.fetch_add(1);
    if (status == 0 || closing.size() >= limits_.max_waiting) return close_now(fd);
    answer(fd, status);
    arriving.erase(fd);
    closing[fd] = Clock::now() + std::chrono::seconds(1);
  };
  serving_.store(true);
  epoll_event events[64];
  while (!stop_.load()) {
    const int n = ::epoll_wait(ep, events, 64, 100);
    const auto now = Clock::now();
    for (int i = 0; i < n; ++i) {
      const int fd = events[i].data.fd;
      if (fd == listen_fd) {
        for (;;) {
          const int client = ::accept4(listen_fd, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
          if (client < 0) break;
          if (arriving.size() >= limits_.max_waiting) {
            const auto oldest = std::min_element(arriving.begin(), arriving.end(),
                                                 [](const auto& a, const auto& b) { return a.second < b.second; });
            drop(oldest->first);
          }
          epoll_event e{};
          e.events = EPOLLIN | EPOLLRDHUP;
          e.data.fd = client;
          if (::epoll_ctl(ep, EPOLL_CTL_ADD, client, &e) != 0) {
            ::close(client);
            continue;
          }
          arriving[client] = now;
        }
        continue;
      }
      if (closing.count(fd) != 0) {
        if (!drain(fd)) close_now(fd);
        continue;
      }
      if (arriving.count(fd) == 0) continue;
      const Arrival a = arrival(fd, &peek, limits_.max_head_bytes, limits_.max_body_bytes);
      switch (a.kind) {
        case Arrival::kWaiting:
          break;
        case Arrival::kRefuse:
          drop(fd, a.status);
          break;
        case Arrival::kWhole:
          ::epoll_ctl(ep, EPOLL_CTL_DEL, fd, nullptr);
          arriving.erase(fd);
          ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) & ~O_NONBLOCK);
          if (limits_.urgent && limits_.urgent(std::string_view(peek.data(), a.head_bytes)))
            workers->enqueue_first([this, fd] { process_and_close_socket(fd); });
          else
            workers->enqueue([this, fd] { process_and_close_socket(fd); });
          break;
      }
    }
    for (auto it = arriving.begin(); it != arriving.end();) {
      const int fd = it->first;
      const bool late = now - it->second > limits_.arrival_deadline;
      ++it;
      if (late) drop(fd);
    }
    for (auto it = closing.begin(); it != closing.end();) {
      const int fd = it->first;
      const bool due = now > it->second;
      ++it;
      if (due) close_now(fd);
    }
  }
  while (!arriving.empty()) close_now(arriving.begin()->first);
  while (!closing.empty()) close_now(closing.begin()->first);
  ::close(ep);
  const int sock = svr_sock_.exchange(-1);
  if (sock >= 0) {
    ::shutdown(sock, SHUT_RDWR);
    ::close(sock);
  }
  workers->shutdown();  // the workers finish what they hold (event streams end with the hub)
  serving_.store(false);
  return true;
}

bool FrontedServer::process_and_close_socket(socket_t sock) {
  SocketStream stream(sock, limits_.read_timeout_ms, limits_.write_timeout_ms,
                      Clock::now() + std::chrono::milliseconds(limits_.worker_read_deadline_ms));
  bool closed = false;
  const bool ok = process_request(stream, /*close_connection=*/true, closed, [](httplib::Request&) {});
  ::shutdown(sock, SHUT_RDWR);
  ::close(sock);
  return ok;
}

}  // namespace lftrack::watch
