// Modbus replies as the couch driver parses them (drivers/modbus_couch.hpp), over TCP on
// loopback: a server thread in this process accepts the driver's connection and answers each
// request with bytes the fuzzer chose. The driver opens, reads back, commands and holds through
// whatever comes back. Every answer must end as a status: a crash, a sanitizer report or a hang
// is a finding, and so is a read-back accepted with a value the register map cannot hold, or a
// driver that calls itself connected after it said the link was gone.
//
// Input: byte 0 picks the client's calls (two bits each: read back, command, hold, read back);
// the rest is the server's script, one reply per request:
//   flags (1 byte)  bit 0: copy the request's transaction id into the reply
//                   bit 1: set the MBAP length field from the reply's own length
//                   bit 2: close the connection instead of answering
//                   bit 3: answer nothing (the driver's response timeout runs out)
//   length (1 byte), then that many bytes of reply (an MBAP header first, as on the wire).
// When the script runs out, or no request comes for 10 ms, the server closes the connection.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <thread>
#include <vector>

#include "fuzz_input.hpp"
#include "lftrack/drivers/modbus_couch.hpp"

namespace {

// A listening socket of its own per input, on an ephemeral loopback port; the server closes it
// once it has the driver's connection, so the driver's reconnect attempts are refused at once.
int listen_on_loopback(int* port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t n = sizeof a;
  if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || ::listen(fd, 1) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &n) != 0)
    std::abort();  // the harness itself cannot run: not a finding in the driver
  *port = ntohs(a.sin_port);
  return fd;
}

// Waits for `fd` to be readable; false on a silence of `timeout_ms` or when `stop` is readable.
bool wait_readable(int fd, int stop, int timeout_ms) {
  pollfd p[2] = {{fd, POLLIN, 0}, {stop, POLLIN, 0}};
  return ::poll(p, 2, timeout_ms) > 0 && p[1].revents == 0 && p[0].revents != 0;
}

// Reads one Modbus TCP request (MBAP header and PDU); false on EOF, error, the harness's stop or
// a silence of kSilenceMs (the driver is then waiting for a reply that is not coming: closing
// ends its wait).
constexpr int kSilenceMs = 10;
bool read_request(int fd, int stop, std::uint8_t* transaction) {
  std::uint8_t header[7];
  std::size_t got = 0;
  while (got < sizeof header) {
    if (!wait_readable(fd, stop, kSilenceMs)) return false;
    const ssize_t n = ::recv(fd, header + got, sizeof header - got, 0);
    if (n <= 0) return false;
    got += std::size_t(n);
  }
  transaction[0] = header[0];
  transaction[1] = header[1];
  std::size_t rest = std::size_t((header[4] << 8) | header[5]);
  rest = rest > 0 ? rest - 1 : 0;
  std::uint8_t pdu[260];
  while (rest > 0) {
    if (!wait_readable(fd, stop, kSilenceMs)) return false;
    const ssize_t n = ::recv(fd, pdu, std::min(rest, sizeof pdu), 0);
    if (n <= 0) return false;
    rest -= std::size_t(n);
  }
  return true;
}

// Closes with a reset, not a FIN: neither end keeps the port in TIME_WAIT, so millions of
// inputs do not run the host out of ephemeral ports.
void close_with_reset(int fd) {
  const linger reset{1, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_LINGER, &reset, sizeof reset);
  ::close(fd);
}

void serve(int listen_fd, int stop, const std::uint8_t* script, std::size_t size) {
  const int fd = wait_readable(listen_fd, stop, 1000) ? ::accept4(listen_fd, nullptr, nullptr, SOCK_CLOEXEC) : -1;
  ::close(listen_fd);
  if (fd < 0) return;
  std::size_t at = 0;
  std::uint8_t transaction[2];
  while (at + 2 <= size && read_request(fd, stop, transaction)) {
    const std::uint8_t flags = script[at];
    const std::size_t length = std::min<std::size_t>(script[at + 1], size - at - 2);
    std::vector<std::uint8_t> reply(script + at + 2, script + at + 2 + length);
    at += 2 + length;
    if ((flags & 4) != 0) break;
    if ((flags & 8) != 0) continue;
    if ((flags & 1) != 0 && reply.size() >= 2) std::memcpy(reply.data(), transaction, 2);
    if ((flags & 2) != 0 && reply.size() >= 6) {
      const std::size_t mbap_length = reply.size() - 6;
      reply[4] = static_cast<std::uint8_t>(mbap_length >> 8);
      reply[5] = static_cast<std::uint8_t>(mbap_length & 0xFF);
    }
    if (!reply.empty() && ::send(fd, reply.data(), reply.size(), MSG_NOSIGNAL) < 0) break;
  }
  close_with_reset(fd);
}

void check_readback(const lftrack::drivers::ActuatorState& state) {
  // The map holds 32-bit micrometres and microradians: anything finite beyond that was invented.
  for (int i = 0; i < 6; ++i) {
    const double limit = i < 3 ? 2147484.0 : 2147.5;
    if (!std::isfinite(state.position(i)) || !std::isfinite(state.target(i)) ||
        std::abs(state.position(i)) > limit || std::abs(state.target(i)) > limit)
      std::abort();
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  using drivers::DeviceStatus;
  if (size < 1 || size > 4096) return 0;
  int port = 0;
  const int listen_fd = listen_on_loopback(&port);
  int stop[2];
  if (::pipe2(stop, O_CLOEXEC) != 0) std::abort();
  std::thread server(serve, listen_fd, stop[0], data + 1, size - 1);

  drivers::ModbusCouchOptions options;
  options.port = port;
  options.response_timeout_s = 0.003;
  options.reconnect_interval_s = 60;  // the reconnect thread never runs within one input
  {
    drivers::ModbusCouch couch(options);
    const Status opened = couch.open();
    fuzz::expect_reason(opened);
    if (opened.ok()) {
      const std::uint8_t calls = data[0];
      for (int i = 0; i < 4; ++i) {
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(20);
        DeviceStatus s = DeviceStatus::kOk;
        switch ((calls >> (2 * i)) & 3) {
          case 0:
          case 3: {
            drivers::ActuatorState state;
            s = couch.readback(&state, deadline);
            if (s == DeviceStatus::kOk) check_readback(state);
            break;
          }
          case 1: {
            tracking::Vector6d correction;
            correction << 0.5, -0.25, 0.1, 0.001, -0.002, 0.0005;
            s = couch.command(correction, deadline);
            break;
          }
          case 2:
            couch.hold();
            break;
        }
        if (s == DeviceStatus::kDisconnected && couch.connected()) std::abort();
      }
    }
    // The server resets the connection before the driver closes its end (no TIME_WAIT).
    (void)!::write(stop[1], "x", 1);
    server.join();
  }
  ::close(stop[0]);
  ::close(stop[1]);
  return 0;
}
