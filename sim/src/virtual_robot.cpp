#include "lftrack/sim/virtual_robot.hpp"

#include <linux/can.h>
#include <linux/can/error.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>

#include "lftrack/drivers/can_robot_protocol.hpp"

namespace lftrack::sim {

namespace can = drivers::robot_can;

Result<std::array<int, 2>> can_socket_pair() {
  int fds[2];
  if (::socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, fds) != 0)
    return io_error(std::string("CAN socket pair: ") + std::strerror(errno));
  return std::array<int, 2>{fds[0], fds[1]};
}

VirtualRobot::VirtualRobot(drivers::Actuator* device, int fd, const VirtualRobotOptions& options)
    : device_(device), fd_(fd), options_(options) {}

Result<std::unique_ptr<VirtualRobot>> VirtualRobot::start(drivers::Actuator* device, int socket_fd,
                                                          const VirtualRobotOptions& options) {
  if (device == nullptr || socket_fd < 0) return invalid_argument("virtual robot: no device or socket");
  std::unique_ptr<VirtualRobot> robot(new VirtualRobot(device, socket_fd, options));
  robot->thread_ = std::thread([r = robot.get()] { r->run(); });
  return robot;
}

VirtualRobot::~VirtualRobot() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  ::close(fd_);
}

void VirtualRobot::inject(RobotFault fault) {
  std::lock_guard lock(faults_mutex_);
  pending_faults_.push_back(fault);
}

void VirtualRobot::send(const can_frame& frame) {
  (void)::send(fd_, &frame, sizeof frame, MSG_DONTWAIT | MSG_NOSIGNAL);
}

void VirtualRobot::heartbeat() {
  if (!heartbeat_on_) return;
  can_frame f = can::make_frame(can::kHeartbeat, options_.node_id, 2);
  f.data[0] = booting_ ? can::kStateBootUp : enabled_ ? can::kStateOperational : can::kStatePreOperational;
  f.data[1] = heartbeat_counter_++;
  booting_ = false;
  send(f);
}

void VirtualRobot::apply(RobotFault fault) {
  can_frame e;
  std::memset(&e, 0, sizeof e);
  e.can_dlc = CAN_ERR_DLC;
  switch (fault) {
    case RobotFault::kBusOff:
      e.can_id = CAN_ERR_FLAG | CAN_ERR_BUSOFF;
      send(e);
      break;
    case RobotFault::kErrorPassive:
      e.can_id = CAN_ERR_FLAG | CAN_ERR_CRTL;
      e.data[1] = CAN_ERR_CRTL_TX_PASSIVE;
      send(e);
      break;
    case RobotFault::kErrorActive:
      e.can_id = CAN_ERR_FLAG | CAN_ERR_CRTL;
      e.data[1] = CAN_ERR_CRTL_ACTIVE;
      send(e);
      break;
    case RobotFault::kControllerRestarted:
      e.can_id = CAN_ERR_FLAG | CAN_ERR_RESTARTED;
      send(e);
      break;
    case RobotFault::kRobotRestart:
      device_->hold();
      enabled_ = false;
      beam_permit_ = false;
      booting_ = true;
      heartbeat();
      break;
    case RobotFault::kStopHeartbeat:
      heartbeat_on_ = false;
      break;
    case RobotFault::kResumeHeartbeat:
      heartbeat_on_ = true;
      heartbeat();
      break;
    case RobotFault::kErrorFlood:
      e.can_id = CAN_ERR_FLAG | CAN_ERR_BUSERROR | CAN_ERR_PROT;
      for (int i = 0; i < options_.flood_frames; ++i) send(e);
      break;
  }
}

void VirtualRobot::handle(const can_frame& f) {
  const canid_t id = f.can_id & CAN_SFF_MASK;
  const auto n = static_cast<canid_t>(options_.node_id);
  if (id == can::kCorrectionTranslation + n && f.can_dlc == 8) {
    translation_ = f;
    have_translation_ = true;
  } else if (id == can::kCorrectionRotation + n && f.can_dlc == 8) {
    can_frame ack = can::make_frame(can::kAcknowledge, options_.node_id, 2);
    ack.data[0] = f.data[6];
    if (!have_translation_ || translation_.data[6] != f.data[6]) return;  // incomplete: no answer
    have_translation_ = false;
    if (!enabled_) {
      ack.data[1] = can::kAckNotEnabled;
    } else if (device_->command(can::decode_correction(translation_, f), {}) != drivers::DeviceStatus::kOk) {
      ack.data[1] = can::kAckOutOfRange;
    } else {
      ack.data[1] = can::kAckAccepted;
      ++corrections_;
    }
    send(ack);
  } else if (id == can::kControl + n && f.can_dlc >= 1) {
    if (f.data[0] == can::kControlEnable) enabled_ = true;
    if (f.data[0] == can::kControlHold) {
      device_->hold();
      enabled_ = false;
    }
  } else if (id == can::kBeamPermit + n && f.can_dlc >= 1) {
    beam_permit_ = f.data[0] != 0;
  } else if (id == can::kReadbackRequest + n && f.can_dlc >= 1) {
    drivers::ActuatorState state;
    const bool ok = device_->readback(&state, {}) == drivers::DeviceStatus::kOk;
    can_frame status = can::make_frame(can::kStatus, options_.node_id, 4);
    status.data[0] = f.data[0];
    status.data[1] = enabled_ ? can::kStateOperational : can::kStatePreOperational;
    status.data[2] = ok && !state.fault ? 0 : 1;
    status.data[3] =
        static_cast<std::uint8_t>((state.moving ? can::kFlagMoving : 0) | (enabled_ ? can::kFlagEnabled : 0) |
                                  (beam_permit_ ? can::kFlagBeamPermit : 0));
    send(status);
    can_frame travel[3];
    if (can::encode_travel(state.position, can::kPositionFirst, options_.node_id, travel))
      for (const can_frame& t : travel) send(t);
    if (can::encode_travel(state.target, can::kTargetFirst, options_.node_id, travel))
      for (const can_frame& t : travel) send(t);
  }
}

void VirtualRobot::run() {
  using Clock = std::chrono::steady_clock;
  const auto period = std::chrono::microseconds(static_cast<long long>(options_.heartbeat_period_s * 1e6));
  auto next_heartbeat = Clock::now();
  while (!stop_) {
    {
      std::vector<RobotFault> faults;
      {
        std::lock_guard lock(faults_mutex_);
        faults.swap(pending_faults_);
      }
      for (RobotFault f : faults) apply(f);
    }
    if (Clock::now() >= next_heartbeat) {
      heartbeat();
      next_heartbeat += period;
    }
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, 2) <= 0) continue;
    if ((p.revents & (POLLHUP | POLLERR)) != 0) {  // the driver closed its end
      link_closed_.store(true);
      break;
    }
    can_frame f;
    for (int i = 0; i < 64; ++i) {
      const ssize_t got = ::recv(fd_, &f, sizeof f, MSG_DONTWAIT);
      if (got != ssize_t(sizeof f)) break;
      handle(f);
    }
  }
}

}  // namespace lftrack::sim
