#include "lftrack/watch/listen_address.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace lftrack::watch {

bool ListenAddress::loopback() const { return address.rfind("127.", 0) == 0; }
bool ListenAddress::wildcard() const { return address == "0.0.0.0"; }
std::string ListenAddress::text() const { return address + ":" + std::to_string(port); }

std::string reachable_warning(const ListenAddress& at, const std::string& server, const std::string& can) {
  if (at.loopback()) return {};
  return server + " listens on " + at.text() + (at.wildcard() ? " (every interface)" : "") +
         ": other hosts can reach it and " + can + "; listen on 127.0.0.1 unless another host must reach it";
}

Result<ListenAddress> parse_listen_address(const std::string& text) {
  ListenAddress a;
  std::string port = text;
  const auto colon = text.rfind(':');
  if (colon != std::string::npos) {
    a.address = text.substr(0, colon);
    port = text.substr(colon + 1);
    if (a.address == "localhost") a.address = "127.0.0.1";
    in_addr parsed{};
    if (a.address.empty() || inet_pton(AF_INET, a.address.c_str(), &parsed) != 1)
      return invalid_argument("'" + text + "': the address must be an IPv4 address (e.g. 127.0.0.1) or localhost");
    char canonical[INET_ADDRSTRLEN] = {};
    inet_ntop(AF_INET, &parsed, canonical, sizeof canonical);
    a.address = canonical;
  }
  if (port.empty() || port.size() > 5 || port.find_first_not_of("0123456789") != std::string::npos)
    return invalid_argument("'" + text + "': expected [ADDRESS:]PORT with PORT a number from 0 to 65535");
  a.port = std::stoi(port);
  if (a.port > 65535) return invalid_argument("'" + text + "': the port must be 0 to 65535");
  return a;
}

Result<int> open_listening_socket(const ListenAddress& where, int* port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
  if (fd < 0) return io_error(std::string("socket: ") + std::strerror(errno));
  const int on = 1;
  ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &on, sizeof on);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(where.port));
  inet_pton(AF_INET, where.address.c_str(), &addr.sin_addr);
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0 || ::listen(fd, 16) != 0) {
    const int error = errno;
    ::close(fd);
    return io_error("cannot listen on " + where.text() + ": " + std::strerror(error));
  }
  socklen_t length = sizeof addr;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &length);
  *port = ntohs(addr.sin_port);
  return fd;
}

}  // namespace lftrack::watch
