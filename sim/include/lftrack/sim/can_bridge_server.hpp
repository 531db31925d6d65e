#pragma once
// A CAN bridge in a process of its own (`lftrack serve robot --socket PATH`): the virtual robot
// behind a local socket that carries struct can_frame records, one per datagram
// (SOCK_SEQPACKET), as a CAN-to-Ethernet or CAN-to-USB bridge's daemon would. The robot driver
// connects with `actuator: {type: can, can: {bridge: PATH}}` (drivers/can_robot.hpp).
//
// One controller at a time: a second connection while one is linked is closed at once. When the
// controller goes away the robot's link ends, and the next connection gets a robot that has just
// booted (boot-up heartbeat), as a replugged bridge would give. unplug() cuts the link from this
// side; inject() passes a fault to the robot now linked.

#include <atomic>
#include <filesystem>
#include <memory>
#include <mutex>
#include <thread>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/sim/virtual_robot.hpp"

namespace lftrack::sim {

class CanBridgeServer {
 public:
  // Listens on `path` (mode 0600). A stale socket there (nobody listening) is replaced; any
  // other file is refused. `device` must outlive the server.
  static Result<std::unique_ptr<CanBridgeServer>> start(const std::filesystem::path& path,
                                                        drivers::Actuator* device,
                                                        const VirtualRobotOptions& options = {});
  ~CanBridgeServer();  // closes the link and removes the socket
  CanBridgeServer(const CanBridgeServer&) = delete;
  CanBridgeServer& operator=(const CanBridgeServer&) = delete;

  void unplug();                     // the link is cut; the controller may connect again
  bool inject(RobotFault fault);     // false: no controller linked
  std::int64_t connections() const { return connections_.load(); }
  std::int64_t refused() const { return refused_.load(); }
  bool linked() const;

 private:
  CanBridgeServer(std::filesystem::path path, int listen_fd, drivers::Actuator* device,
                  const VirtualRobotOptions& options)
      : path_(std::move(path)), listen_fd_(listen_fd), device_(device), options_(options) {}
  void accept_loop();

  std::filesystem::path path_;
  int listen_fd_;
  drivers::Actuator* device_;
  VirtualRobotOptions options_;
  mutable std::mutex mutex_;
  std::unique_ptr<VirtualRobot> robot_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<std::int64_t> connections_{0}, refused_{0};
};

}  // namespace lftrack::sim
