#pragma once
// What the protocol tests share: deadlines from now, small corrections, and the virtual couch
// (also the robot's dynamics) made safe to share between a protocol peer's thread and the
// test's clock.

#include <chrono>
#include <mutex>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/sim/virtual_couch.hpp"

namespace lftrack::test {

inline drivers::Deadline in_ms(double ms) {
  return std::chrono::steady_clock::now() + std::chrono::microseconds(static_cast<long long>(ms * 1000));
}

// x translation (mm) and z rotation (rad).
inline tracking::Vector6d shift(double x_mm, double rz_rad = 0) {
  tracking::Vector6d v = tracking::Vector6d::Zero();
  v(0) = x_mm;
  v(5) = rz_rad;
  return v;
}

class LockedCouch final : public drivers::Actuator {
 public:
  explicit LockedCouch(const sim::VirtualCouchSpec& spec) : couch_(spec) {}
  Status open() override { return {}; }
  drivers::DeviceStatus command(const tracking::Vector6d& c, drivers::Deadline d) override {
    std::lock_guard lock(mutex_);
    return couch_.command(c, d);
  }
  drivers::DeviceStatus readback(drivers::ActuatorState* s, drivers::Deadline d) override {
    std::lock_guard lock(mutex_);
    return couch_.readback(s, d);
  }
  void hold() override {
    std::lock_guard lock(mutex_);
    couch_.hold();
  }
  void close() override {}
  void advance_to(double t_s) {
    std::lock_guard lock(mutex_);
    couch_.advance_to(t_s);
  }
  tracking::Vector6d position() {
    std::lock_guard lock(mutex_);
    return couch_.position();
  }

 private:
  std::mutex mutex_;
  sim::VirtualCouch couch_;
};

}  // namespace lftrack::test
