#pragma once
// Where a watcher's server listens: "[ADDRESS:]PORT" on the command line (--monitor, --igtl).
// ADDRESS is an IPv4 address in dotted decimal or "localhost"; without one, 127.0.0.1 (loopback:
// nothing outside this host reaches the server unless the operator names an address). PORT is 0
// (any free port, said at start) to 65535.

#include <cstdint>
#include <string>

#include "lftrack/tracking/status.hpp"

namespace lftrack::watch {

struct ListenAddress {
  std::string address = "127.0.0.1";  // dotted IPv4
  int port = 0;
  bool loopback() const;     // 127.0.0.0/8
  bool wildcard() const;     // 0.0.0.0: every interface
  std::string text() const;  // "ADDRESS:PORT"
};

Result<ListenAddress> parse_listen_address(const std::string& text);

// For a server listening where other hosts reach it (any address outside 127.0.0.0/8), the
// warning it gives at start: `server` listens on ADDRESS:PORT, other hosts can reach it and `can`
// (what whoever reaches it may do); empty on loopback. The monitor page, the OpenIGTLink server
// and `lftrack serve couch` give it.
std::string reachable_warning(const ListenAddress& at, const std::string& server, const std::string& can);

// Opens a TCP socket listening on `where` (SO_REUSEADDR, close-on-exec, non-blocking) and says
// which port it took (`where.port` 0: the kernel's choice). The caller closes the descriptor.
Result<int> open_listening_socket(const ListenAddress& where, int* port);

}  // namespace lftrack::watch
