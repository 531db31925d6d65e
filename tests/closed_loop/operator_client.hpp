#pragma once
// The operator at the control socket (operator_input.hpp), as a test drives it: sends a
// datagram, reads the reply, and answers whatever state the loop is in with the command that
// leaves it (resume the HOLD by its id, reset the FAULT, resume from IDLE).

#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>
#include <thread>

namespace lftrack::session {

class OperatorClient {
 public:
  OperatorClient(const std::filesystem::path& control, const std::filesystem::path& self) : control_(control) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_un me{};
    me.sun_family = AF_UNIX;
    std::strncpy(me.sun_path, self.c_str(), sizeof(me.sun_path) - 1);
    ::bind(fd_, reinterpret_cast<const sockaddr*>(&me), sizeof me);
    timeval timeout{0, 50000};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
  }
  ~OperatorClient() { ::close(fd_); }
  OperatorClient(const OperatorClient&) = delete;
  OperatorClient& operator=(const OperatorClient&) = delete;

  // The reply to `text` (empty: none within `waits` x 50 ms, or the loop has gone).
  std::string ask(const std::string& text, int waits = 6) {
    sockaddr_un to{};
    to.sun_family = AF_UNIX;
    std::strncpy(to.sun_path, control_.c_str(), sizeof(to.sun_path) - 1);
    char drain[256];
    while (::recv(fd_, drain, sizeof drain, MSG_DONTWAIT) > 0) {
    }
    if (::sendto(fd_, text.data(), text.size(), 0, reinterpret_cast<const sockaddr*>(&to), sizeof to) < 0) return {};
    for (int i = 0; i < waits; ++i) {  // the loop answers once a cycle (100 ms)
      char buffer[256];
      const ssize_t n = ::recv(fd_, buffer, sizeof buffer, 0);
      if (n > 0) return std::string(buffer, std::size_t(n));
    }
    return {};
  }
  // The cycle a status reply names ("TRACK cycle 12: ok"), or -1.
  static long long cycle_of(const std::string& status) {
    const std::size_t at = status.find(" cycle ");
    long long n = -1;
    if (at == std::string::npos || std::sscanf(status.c_str() + at, " cycle %lld", &n) != 1) return -1;
    return n;
  }
  // Waits (status every 100 ms) until the loop's state starts with `state`; the reply, or empty
  // after `timeout`.
  std::string wait_for(const std::string& state, std::chrono::milliseconds timeout) {
    const auto until = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < until) {
      const std::string reply = ask("status");
      if (reply.rfind(state, 0) == 0) return reply;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return {};
  }
  // Waits until the loop is held or stopped (HOLD or FAULT); the reply, or empty after `timeout`.
  std::string wait_for_safe(std::chrono::milliseconds timeout) {
    const auto until = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < until) {
      const std::string reply = ask("status");
      if (reply.rfind("HOLD", 0) == 0 || reply.rfind("FAULT", 0) == 0) return reply;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return {};
  }
  // Waits until the loop's status names cycle `at_least` or later, in any state; that cycle, or
  // -1 after `timeout`.
  long long wait_for_cycle(long long at_least, std::chrono::milliseconds timeout) {
    const auto until = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < until) {
      const long long c = cycle_of(ask("status"));
      if (c >= at_least) return c;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return -1;
  }
  // Brings the loop back to TRACK as an operator would, one command per state it shows; true
  // once it tracks.
  bool bring_back_to_track(std::chrono::milliseconds timeout) {
    const auto until = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < until) {
      const std::string reply = ask("status");
      unsigned id = 0;
      if (reply.rfind("TRACK", 0) == 0) return true;
      if (std::sscanf(reply.c_str(), "HOLD %u", &id) == 1) ask("resume " + std::to_string(id));
      if (std::sscanf(reply.c_str(), "FAULT %u", &id) == 1) ask("reset " + std::to_string(id));
      if (reply.rfind("IDLE", 0) == 0) ask("resume");
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    return false;
  }

 private:
  std::filesystem::path control_;
  int fd_ = -1;
};

}  // namespace lftrack::session
