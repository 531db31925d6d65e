#pragma once
// The virtual couch as a device of its own, on the real clock: what `lftrack serve couch` and
// `lftrack serve robot` put behind their protocols. Every call first moves the couch on to
// CLOCK_MONOTONIC now (a VirtualCouch under a lock, so the protocol's thread and the publisher
// may share it). With a room link, a thread publishes the couch's position every millisecond
// for the simulated detectors in other processes (room_link.hpp).

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <thread>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/sim/room_link.hpp"
#include "lftrack/sim/virtual_couch.hpp"

namespace lftrack::sim {

class ServedCouch final : public drivers::Actuator {
 public:
  // `room_link` empty: no link.
  static Result<std::unique_ptr<ServedCouch>> start(const VirtualCouchSpec& spec,
                                                    const std::filesystem::path& room_link);
  ~ServedCouch() override;

  Status open() override { return {}; }
  drivers::DeviceStatus command(const tracking::Vector6d& correction, drivers::Deadline deadline) override;
  drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline deadline) override;
  void hold() override;
  void set_beam_permit(bool permit) override { beam_permit_.store(permit); }
  void close() override {}

  tracking::Vector6d position() const;
  bool beam_permit() const { return beam_permit_.load(); }
  std::int64_t commands() const { return commands_.load(); }
  std::int64_t holds() const { return holds_.load(); }

 private:
  explicit ServedCouch(const VirtualCouchSpec& spec) : couch_(spec) {}
  void advance_locked() const;  // to now
  void advance_locked_to(std::int64_t t_ns) const;
  void publish_loop();

  mutable std::mutex mutex_;
  mutable VirtualCouch couch_;
  std::int64_t epoch_ns_ = 0;
  std::unique_ptr<RoomLinkWriter> link_;
  std::thread publisher_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> beam_permit_{false};
  std::atomic<std::int64_t> commands_{0}, holds_{0};
};

}  // namespace lftrack::sim
