#include "lftrack/sim/null_modem.hpp"

#include <poll.h>
#include <pty.h>
#include <unistd.h>

namespace lftrack::sim {

NullModem::NullModem() {
  ok_ = openpty(&master_[0], &slave_[0], name_[0], nullptr, nullptr) == 0 &&
        openpty(&master_[1], &slave_[1], name_[1], nullptr, nullptr) == 0;
  if (ok_) thread_ = std::thread([this] { copy(); });
}

NullModem::~NullModem() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  for (int i = 0; i < 2; ++i) {
    if (master_[i] >= 0) ::close(master_[i]);
    if (slave_[i] >= 0) ::close(slave_[i]);
  }
}

void NullModem::copy() {
  char buffer[512];
  while (!stop_) {
    pollfd p[2] = {{master_[0], POLLIN, 0}, {master_[1], POLLIN, 0}};
    if (::poll(p, 2, 10) <= 0) continue;
    for (int i = 0; i < 2; ++i)
      if (p[i].revents & POLLIN) {
        const ssize_t n = ::read(master_[i], buffer, sizeof buffer);
        if (n > 0) (void)!::write(master_[1 - i], buffer, std::size_t(n));
      }
  }
}

}  // namespace lftrack::sim
