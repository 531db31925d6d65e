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

namespace lftrack::host {
namespace {

using Clock = std::chrono::steady_clock;

// A worker's view of a connection whose request is already in the socket's buffer: reads and
// writes with cpp-httplib's per-call timeouts, a small read buffer (the request-line reader asks
// for one byte at a time), writes that never raise SIGPIPE.
class SocketStream final : public httplib::Stream {
 public:
  SocketStream(int fd, int read_timeout_ms, int write_timeout_ms)
      : fd_(fd), read_ms_(read_timeout_ms), write_ms_(write_timeout_ms) {}

  bool is_readable() const override { return wait(POLLIN, read_ms_); }
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
  char buffer_[4096];
  std::size_t have_ = 0, used_ = 0;
};

enum class Arrival { kWaiting, kWhole, kDrop };

// Whether the request waiting on `fd` has arrived whole: the headers' blank line, then as many
// body bytes as Content-Length says. A request with no Content-Length has no body (GET); one
// that sends its body in chunks, a body beyond the limit or a closed connection is dropped.
Arrival arrival(int fd, std::vector<char>* peek, std::size_t max_bytes) {
  const ssize_t n = ::recv(fd, peek->data(), peek->size(), MSG_PEEK | MSG_DONTWAIT);
  if (n == 0) return Arrival::kDrop;
  if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR ? Arrival::kWaiting : Arrival::kDrop;
  const std::string_view text(peek->data(), std::size_t(n));
  const std::size_t end = text.find("\r\n\r\n");
  if (end == std::string_view::npos) return std::size_t(n) >= max_bytes ? Arrival::kDrop : Arrival::kWaiting;
  std::string head(text.substr(0, end));
  std::transform(head.begin(), head.end(), head.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  if (head.find("\r\ntransfer-encoding:") != std::string::npos) return Arrival::kDrop;
  std::size_t body = 0;
  if (const std::size_t at = head.find("\r\ncontent-length:"); at != std::string::npos) {
    const char* digits = head.c_str() + at + 17;
    while (*digits == ' ' || *digits == '\t') ++digits;
    char* stop = nullptr;
    const unsigned long long length = std::strtoull(digits, &stop, 10);
    if (stop == digits) return Arrival::kDrop;
    if (length > max_bytes) return Arrival::kWhole;  // httplib answers 413 from the headers alone
    body = std::size_t(length);
  }
  const std::size_t whole = end + 4 + body;
  if (whole > max_bytes) return Arrival::kWhole;  // the same: refused by its length
  return std::size_t(n) >= whole ? Arrival::kWhole : Arrival::kWaiting;
}

}  // namespace

FrontedServer::FrontedServer(const Limits& limits, std::function<httplib::TaskQueue*()> make_workers)
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
  std::unique_ptr<httplib::TaskQueue> workers(make_workers_());
  const int ep = ::epoll_create1(EPOLL_CLOEXEC);
  if (ep < 0) return false;
  ::fcntl(listen_fd, F_SETFL, ::fcntl(listen_fd, F_GETFL) | O_NONBLOCK);
  epoll_event listen_event{};
  listen_event.events = EPOLLIN;
  listen_event.data.fd = listen_fd;
  ::epoll_ctl(ep, EPOLL_CTL_ADD, listen_fd, &listen_event);
  std::map<int, Clock::time_point> arriving;  // fd -> accepted at
  std::vector<char> peek(limits_.max_request_bytes + 1);
  const auto drop = [&](int fd) {
    ::epoll_ctl(ep, EPOLL_CTL_DEL, fd, nullptr);
    ::close(fd);
    arriving.erase(fd);
    dropped_.fetch_add(1);
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
      if (arriving.count(fd) == 0) continue;
      switch (arrival(fd, &peek, limits_.max_request_bytes)) {
        case Arrival::kWaiting:
          break;
        case Arrival::kDrop:
          drop(fd);
          break;
        case Arrival::kWhole:
          ::epoll_ctl(ep, EPOLL_CTL_DEL, fd, nullptr);
          arriving.erase(fd);
          ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) & ~O_NONBLOCK);
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
  }
  for (auto it = arriving.begin(); it != arriving.end();) {
    const int fd = it->first;
    ++it;
    drop(fd);
  }
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
  SocketStream stream(sock, limits_.read_timeout_ms, limits_.write_timeout_ms);
  bool closed = false;
  const bool ok = process_request(stream, /*close_connection=*/true, closed, [](httplib::Request&) {});
  ::shutdown(sock, SHUT_RDWR);
  ::close(sock);
  return ok;
}

}  // namespace lftrack::host
