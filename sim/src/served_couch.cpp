#include "lftrack/sim/served_couch.hpp"

#include <chrono>

namespace lftrack::sim {

namespace {

std::int64_t served_clock_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace

Result<std::unique_ptr<ServedCouch>> ServedCouch::start(const VirtualCouchSpec& spec,
                                                        const std::filesystem::path& room_link) {
  std::unique_ptr<ServedCouch> couch(new ServedCouch(spec));
  couch->epoch_ns_ = served_clock_ns();
  if (!room_link.empty()) {
    auto link = RoomLinkWriter::create(room_link);
    if (!link.ok()) return link.status();
    couch->link_ = std::move(link).value();
    couch->couch_.place_at(couch->link_->resumed_position());  // a restarted server: where the couch stopped
    couch->link_->publish(couch->link_->resumed_position());
    couch->publisher_ = std::thread([c = couch.get()] { c->publish_loop(); });
  }
  return couch;
}

ServedCouch::~ServedCouch() {
  stop_.store(true);
  if (publisher_.joinable()) publisher_.join();
}

void ServedCouch::advance_locked() const { advance_locked_to(served_clock_ns()); }

void ServedCouch::advance_locked_to(std::int64_t t_ns) const {
  couch_.advance_to(1e-9 * static_cast<double>(t_ns - epoch_ns_));
}

void ServedCouch::publish_loop() {
  while (!stop_.load()) {
    tracking::Vector6d position;
    std::int64_t at_ns = 0;
    {
      std::lock_guard lock(mutex_);
      at_ns = served_clock_ns();  // under the lock: the couch's time never goes back
      advance_locked_to(at_ns);
      position = couch_.position();
    }
    link_->publish(position, at_ns);  // where the couch is at that time, however late it is written
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
}

drivers::DeviceStatus ServedCouch::command(const tracking::Vector6d& correction, drivers::Deadline deadline) {
  std::lock_guard lock(mutex_);
  advance_locked();
  const drivers::DeviceStatus s = couch_.command(correction, deadline);
  if (s == drivers::DeviceStatus::kOk) ++commands_;
  return s;
}

drivers::DeviceStatus ServedCouch::readback(drivers::ActuatorState* state, drivers::Deadline deadline) {
  std::lock_guard lock(mutex_);
  advance_locked();
  return couch_.readback(state, deadline);
}

void ServedCouch::hold() {
  std::lock_guard lock(mutex_);
  advance_locked();
  couch_.hold();
  ++holds_;
}

tracking::Vector6d ServedCouch::position() const {
  std::lock_guard lock(mutex_);
  advance_locked();
  return couch_.position();
}

}  // namespace lftrack::sim
