#include "lftrack/sim/served_couch.hpp"

#include <chrono>
#include <cstdio>

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
    // A restarted server: the couch stands where it stopped, which must be within this couch's
    // travel (a link left by a couch with a wider range, or damaged, is not a place to start from).
    const tracking::Vector6d resumed = couch->link_->resumed_position();
    if (!within_travel(spec, resumed)) {
      couch->link_->leave_file();  // refused, not consumed: the file stays for whoever looks at it
      char why[320];
      std::snprintf(why, sizeof why,
                    ": the couch it left stands at %g %g %g mm, %g %g %g deg, outside this couch's travel (%g mm, "
                    "%g deg per axis); remove the link to start at zero",
                    resumed[0], resumed[1], resumed[2], tracking::rad_to_deg(resumed[3]),
                    tracking::rad_to_deg(resumed[4]), tracking::rad_to_deg(resumed[5]), spec.range_mm, spec.range_deg);
      return failed_precondition("room link " + room_link.string() + why);
    }
    couch->couch_.place_at(resumed);
    couch->link_->publish(resumed);
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
