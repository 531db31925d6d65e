#pragma once
// A serial line between two programs of this host: two pseudo-terminals whose master sides a
// thread joins, copying bytes both ways (what a null-modem cable does). Each end is a tty path a
// program opens as it would a serial port (`lftrack serve couch --modbus rtu:pty` serves Modbus
// RTU on one end; a scene's actuator.modbus.rtu.device names the other).

#include <atomic>
#include <thread>

namespace lftrack::sim {

class NullModem {
 public:
  NullModem();  // ok() says whether the pseudo-terminals could be made
  ~NullModem();
  NullModem(const NullModem&) = delete;
  NullModem& operator=(const NullModem&) = delete;
  bool ok() const { return ok_; }
  const char* end(int i) const { return name_[i]; }  // i = 0 or 1: a tty path

 private:
  void copy();
  int master_[2] = {-1, -1}, slave_[2] = {-1, -1};
  char name_[2][64] = {};
  bool ok_ = false;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace lftrack::sim
