#pragma once
// A raw GVCP client on loopback for tests of the fake GigE cameras (sim/gige_fake_detector.hpp):
// malformed datagrams of many shapes, and a well-formed register read to see that the camera
// still answers afterwards.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace lftrack::test {

// A GVCP command: key 0x42, ack required, `command`, `length` as its length field (whatever the
// payload really is), id 0x4242, then `payload`.
inline std::vector<std::uint8_t> gvcp_datagram(std::uint16_t command, std::uint16_t length,
                                               const std::vector<std::uint32_t>& payload) {
  std::vector<std::uint8_t> d = {0x42, 0x01};
  for (std::uint16_t h : {command, length, std::uint16_t(0x4242)})
    for (int shift : {8, 0}) d.push_back(std::uint8_t(h >> shift));
  for (std::uint32_t w : payload)
    for (int shift : {24, 16, 8, 0}) d.push_back(std::uint8_t(w >> shift));
  return d;
}

// Datagrams a camera must survive: empty, one byte, a truncated header, not a command, a bogus
// command, length fields that lie, reads and writes of unmapped, wrapping, misaligned or
// oversize blocks, a packet resend, and the largest UDP datagram of junk.
inline std::vector<std::vector<std::uint8_t>> malformed_gvcp_datagrams() {
  constexpr std::uint16_t kReadReg = 0x0080, kWriteReg = 0x0082, kReadMem = 0x0084, kWriteMem = 0x0086;
  std::vector<std::vector<std::uint8_t>> d;
  d.push_back({});
  d.push_back({0x42});
  d.push_back({0x42, 0x01, 0x00, 0x80, 0x00, 0x04, 0x00});  // 7 bytes of header
  std::vector<std::uint8_t> not_a_command = gvcp_datagram(kReadReg, 4, {0x1F0});
  not_a_command[0] = 0x00;  // an acknowledge's first byte
  d.push_back(not_a_command);
  d.push_back(gvcp_datagram(0x1234, 0, {}));                   // no such command
  d.push_back(gvcp_datagram(kReadReg, 0xFFFC, {0x1F0}));       // length field far past the datagram
  d.push_back(gvcp_datagram(kReadReg, 6, {0x1F0, 0}));         // length not a multiple of 4
  d.push_back(gvcp_datagram(kReadReg, 0, {}));                 // a read of no register
  d.push_back(gvcp_datagram(kReadReg, 4, {0xFFFFFFFC}));       // unmapped
  d.push_back(gvcp_datagram(kReadReg, 4, {0x7FFFFFF0}));       // unmapped, past the description
  d.push_back(gvcp_datagram(kReadReg, 4, {0x1F1}));            // misaligned
  d.push_back(gvcp_datagram(kReadMem, 8, {0x0000, 0}));        // a read of 0 bytes
  d.push_back(gvcp_datagram(kReadMem, 8, {0x0000, 0xFFFF}));   // 65535 bytes
  d.push_back(gvcp_datagram(kReadMem, 8, {0xFFFFFF00, 512}));  // unmapped
  d.push_back(gvcp_datagram(kReadMem, 8, {0xFFFFFFFC, 8}));    // wraps past 2^32
  d.push_back(gvcp_datagram(kReadMem, 4, {0x0000}));           // no count
  d.push_back(gvcp_datagram(kWriteMem, 8, {0xFFFFFFFC, 1}));   // unmapped, wraps
  d.push_back(gvcp_datagram(kWriteMem, 0xFFF0, {0x0000, 1}));  // length field far past the datagram
  d.push_back(gvcp_datagram(kWriteMem, 8, {0x00010000, 1}));   // into the read-only description
  d.push_back(gvcp_datagram(kWriteReg, 8, {0xFFFFFFF0, 1}));   // unmapped
  d.push_back(gvcp_datagram(kWriteReg, 4, {0x1F0}));           // half a pair
  d.push_back(gvcp_datagram(kWriteReg, 8, {0x1F2, 1}));        // misaligned
  d.push_back(gvcp_datagram(0x0040, 12, {0, 0, 0}));           // packet resend
  d.push_back(gvcp_datagram(0x0002, 0xFFFC, {}));              // discovery whose length lies
  d.push_back(std::vector<std::uint8_t>(65507, 0x42));         // the largest datagram, all key bytes
  return d;
}

// A UDP socket on 127.0.0.1 that talks to a camera's GVCP port.
class GvcpClient {
 public:
  explicit GvcpClient(const std::string& camera) {
    fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    to_.sin_family = AF_INET;
    to_.sin_port = htons(3956);
    ::inet_pton(AF_INET, camera.c_str(), &to_.sin_addr);
  }
  ~GvcpClient() {
    if (fd_ >= 0) ::close(fd_);
  }
  GvcpClient(const GvcpClient&) = delete;
  GvcpClient& operator=(const GvcpClient&) = delete;

  bool send(const std::vector<std::uint8_t>& datagram) const {
    return ::sendto(fd_, datagram.data(), datagram.size(), 0, reinterpret_cast<const sockaddr*>(&to_),
                    sizeof to_) == ssize_t(datagram.size());
  }
  // The next datagram within `timeout`, or nothing.
  std::optional<std::vector<std::uint8_t>> receive(std::chrono::milliseconds timeout) const {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, int(timeout.count())) <= 0) return std::nullopt;
    std::vector<std::uint8_t> d(65536);
    const ssize_t n = ::recv(fd_, d.data(), d.size(), 0);
    if (n < 0) return std::nullopt;
    d.resize(std::size_t(n));
    return d;
  }
  // Reads the register at `address` (READREG, id `id`), sending again every 200 ms as a GVCP
  // client does (a datagram may be lost): its value once the camera acknowledges within
  // `timeout`, or nothing.
  std::optional<std::uint32_t> read_register(std::uint32_t address, std::uint16_t id,
                                             std::chrono::milliseconds timeout) const {
    std::vector<std::uint8_t> d = gvcp_datagram(0x0080, 4, {address});
    d[6] = std::uint8_t(id >> 8);
    d[7] = std::uint8_t(id);
    const auto until = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < until) {
      if (!send(d)) return std::nullopt;
      const auto resend = std::min(until, std::chrono::steady_clock::now() + std::chrono::milliseconds(200));
      for (auto now = std::chrono::steady_clock::now(); now < resend;
           now = std::chrono::steady_clock::now()) {
        const auto ack = receive(std::chrono::duration_cast<std::chrono::milliseconds>(resend - now));
        if (!ack) break;
        const std::vector<std::uint8_t>& a = *ack;
        if (a.size() == 12 && a[0] == 0 && a[1] == 0 && a[2] == 0x00 && a[3] == 0x81 && a[6] == d[6] &&
            a[7] == d[7])
          return (std::uint32_t(a[8]) << 24) | (std::uint32_t(a[9]) << 16) | (std::uint32_t(a[10]) << 8) |
                 a[11];
      }
    }
    return std::nullopt;
  }

 private:
  int fd_ = -1;
  sockaddr_in to_{};
};

}  // namespace lftrack::test
