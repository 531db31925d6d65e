#pragma once
// The virtual beam robot on a CAN link: the other end of the robot driver's socket
// (drivers/can_robot.hpp), speaking the frame layout of drivers/can_robot_protocol.hpp. It
// fronts a device with the robot's dynamics (a VirtualCouch, or the simulated room's couch),
// sends its heartbeat every period, and answers corrections, control, read-back requests and
// the beam permit from its own thread.
//
// The link is a socketpair(AF_UNIX, SOCK_SEQPACKET) carrying struct can_frame (this kernel has
// no CAN), made by can_socket_pair(). Faults are injected as the CAN controller and the robot
// would produce them: error frames for bus-off, error-passive, back to error-active, controller
// restarted and a flood of bus errors; a robot restart (boot-up heartbeat, motion disabled); a
// heartbeat that stops and resumes.

#include <linux/can.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

// Two connected sockets carrying struct can_frame records: [0] for the driver, [1] the robot.
Result<std::array<int, 2>> can_socket_pair();

enum class RobotFault {
  kBusOff,
  kErrorPassive,
  kErrorActive,  // back from error-passive
  kControllerRestarted,
  kRobotRestart,
  kStopHeartbeat,
  kResumeHeartbeat,
  kErrorFlood,
};

struct VirtualRobotOptions {
  int node_id = 1;
  double heartbeat_period_s = 0.05;
  int flood_frames = 300;
};

class VirtualRobot {
 public:
  // Takes ownership of `socket_fd`; `device` must outlive the robot.
  static Result<std::unique_ptr<VirtualRobot>> start(drivers::Actuator* device, int socket_fd,
                                                     const VirtualRobotOptions& options = {});
  ~VirtualRobot();
  VirtualRobot(const VirtualRobot&) = delete;
  VirtualRobot& operator=(const VirtualRobot&) = delete;

  void inject(RobotFault fault);  // acted on by the robot's thread at once
  bool beam_permit() const { return beam_permit_.load(); }
  std::int64_t corrections() const { return corrections_.load(); }
  bool enabled() const { return enabled_.load(); }
  bool link_closed() const { return link_closed_.load(); }  // the driver closed its end

 private:
  VirtualRobot(drivers::Actuator* device, int fd, const VirtualRobotOptions& options);
  void run();
  void handle(const can_frame& frame);
  void apply(RobotFault fault);
  void send(const can_frame& frame);
  void heartbeat();

  drivers::Actuator* device_;
  int fd_;
  VirtualRobotOptions options_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::mutex faults_mutex_;
  std::vector<RobotFault> pending_faults_;
  std::atomic<bool> enabled_{false}, beam_permit_{false};
  std::atomic<std::int64_t> corrections_{0};
  std::atomic<bool> link_closed_{false};
  bool heartbeat_on_ = true, booting_ = true;
  std::uint8_t heartbeat_counter_ = 0;
  can_frame translation_{};  // the first half of the correction being received
  bool have_translation_ = false;
};

}  // namespace lftrack::sim
