#include "lftrack/drivers/can_robot.hpp"

#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>

#include "lftrack/drivers/can_robot_protocol.hpp"

namespace lftrack::drivers {

namespace can = robot_can;
namespace {
constexpr int kMaxFramesPerPump = 256;
}

std::string describe_can_faults(std::uint32_t f) {
  std::string s;
  const auto add = [&](std::uint32_t bit, const char* what) {
    if ((f & bit) == 0) return;
    if (!s.empty()) s += ", ";
    s += what;
  };
  add(kCanBusOff, "bus-off");
  add(kCanErrorPassive, "error-passive");
  add(kCanControllerRestarted, "CAN controller restarted");
  add(kCanRobotRestarted, "robot restarted");
  add(kCanHeartbeatMissing, "heartbeat missing");
  add(kCanErrorFlood, "error-frame flood");
  add(kCanRobotFault, "robot reports a fault");
  return s.empty() ? "none" : s;
}

CanRobot::CanRobot(CanRobotOptions options) : options_(std::move(options)) {}
CanRobot::CanRobot(CanRobotOptions options, int socket_fd)
    : options_(std::move(options)), fd_(socket_fd), given_socket_(true) {}
CanRobot::~CanRobot() {
  close();
}

std::int64_t CanRobot::now_ns() const {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

Status CanRobot::open() {
  if (options_.node_id < 1 || options_.node_id > 15)
    return invalid_argument("CAN robot: node id must be in 1..15");
  const bool bridge = !given_socket_ && !options_.bridge_path.empty();
  const std::string where = given_socket_ ? std::string("CAN robot on a socket")
                            : bridge      ? "CAN robot through the bridge " + options_.bridge_path
                                          : "CAN robot on " + options_.interface;
  if (bridge) {
    if (!(options_.reconnect_interval_s > 0) || options_.reconnect_interval_s > 60)
      return invalid_argument(where + ": reconnect interval must be in (0, 60] s");
    LFTRACK_RETURN_IF_ERROR(connect_bridge());
  } else if (!given_socket_) {
    fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
    if (fd_ < 0)
      return io_error(where + ": no CAN_RAW socket (" + std::strerror(errno) +
                      "); this kernel may have no CAN support (modprobe can_raw; vcan for tests)");
    ifreq request{};
    std::strncpy(request.ifr_name, options_.interface.c_str(), IFNAMSIZ - 1);
    if (::ioctl(fd_, SIOCGIFINDEX, &request) != 0) {
      close();
      return not_found(where + ": no such interface (" + std::strerror(errno) + ")");
    }
    sockaddr_can address{};
    address.can_family = AF_CAN;
    address.can_ifindex = request.ifr_ifindex;
    can_err_mask_t errors = CAN_ERR_CRTL | CAN_ERR_BUSOFF | CAN_ERR_RESTARTED | CAN_ERR_BUSERROR |
                            CAN_ERR_PROT | CAN_ERR_TX_TIMEOUT | CAN_ERR_ACK;
    const canid_t n = static_cast<canid_t>(options_.node_id);
    can_filter filters[9] = {{can::kAcknowledge + n, CAN_SFF_MASK},
                             {can::kStatus + n, CAN_SFF_MASK},
                             {can::kHeartbeat + n, CAN_SFF_MASK}};
    for (canid_t k = 0; k < 6; ++k) filters[3 + k] = {can::kPositionFirst + n + k, CAN_SFF_MASK};
    if (::setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &errors, sizeof errors) != 0 ||
        ::setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FILTER, filters, sizeof filters) != 0 ||
        ::bind(fd_, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
      const std::string why = std::strerror(errno);
      close();
      return io_error(where + ": " + why);
    }
  }
  if (fd_ < 0) return failed_precondition(where + ": no socket");
  link_up_ = true;
  const auto until = std::chrono::steady_clock::now() +
                     std::chrono::microseconds(static_cast<long long>(options_.open_timeout_s * 1e6));
  const std::uint32_t seen_before = seen_;
  while (last_heartbeat_ns_ == 0 && std::chrono::steady_clock::now() < until) {
    pollfd p{fd_, POLLIN, 0};
    ::poll(&p, 1, 10);
    pump();
  }
  if (last_heartbeat_ns_ == 0)
    return io_error(where + ": no heartbeat from node " + std::to_string(options_.node_id) + " within " +
                    std::to_string(options_.open_timeout_s) + " s");
  // A robot that has just booted is expected: neither a fault now nor one seen.
  latched_ &= ~std::uint32_t(kCanRobotRestarted);
  seen_ = (seen_ & ~std::uint32_t(kCanRobotRestarted)) | (seen_before & kCanRobotRestarted);
  return {};
}

Status CanRobot::connect_bridge() {
  last_connect_attempt_ns_ = now_ns();
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  if (options_.bridge_path.size() >= sizeof address.sun_path)
    return invalid_argument("CAN bridge path is too long (at most " + std::to_string(sizeof address.sun_path - 1) +
                            " bytes): " + options_.bridge_path);
  std::memcpy(address.sun_path, options_.bridge_path.data(), options_.bridge_path.size());
  const int fd = ::socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
  if (fd < 0) return io_error(std::string("CAN bridge: socket: ") + std::strerror(errno));
  if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
    const int e = errno;
    ::close(fd);
    return io_error("CAN bridge " + options_.bridge_path + ": " + std::strerror(e) +
                       (e == ENOENT || e == ECONNREFUSED ? " (is `lftrack serve robot` running?)" : ""));
  }
  fd_ = fd;
  return {};
}

void CanRobot::link_lost() {
  if (!link_up_) return;  // counted once per loss
  link_up_ = false;
  ++counters_.disconnects;
  enabled_ = false;
  // A bridge is dialled again from the cycle; a given socket's peer is gone for good. A CAN_RAW
  // socket stays: frames flow again when its interface is back.
  if ((given_socket_ || !options_.bridge_path.empty()) && fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
}

void CanRobot::link_regained() {
  if (link_up_) return;
  link_up_ = true;
  ++counters_.reconnects;
}

bool CanRobot::linked() {
  if (fd_ >= 0) return true;
  if (options_.bridge_path.empty() || given_socket_) return false;
  if (double(now_ns() - last_connect_attempt_ns_) < options_.reconnect_interval_s * 1e9) return false;
  if (!connect_bridge().ok()) return false;
  link_regained();
  // Whatever answers now has not seen our commands: treated as a restarted robot.
  latched_ |= kCanRobotRestarted;
  seen_ |= kCanRobotRestarted;
  enabled_ = false;
  status_fresh_ = ack_fresh_ = false;
  return true;
}

void CanRobot::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  link_up_ = false;  // closed on purpose: no loss to count
}

DeviceStatus CanRobot::send(const can_frame& frame) {
  if (::send(fd_, &frame, sizeof frame, MSG_DONTWAIT | MSG_NOSIGNAL) == ssize_t(sizeof frame)) {
    ++counters_.frames_out;
    link_regained();  // a CAN_RAW interface that is back
    return DeviceStatus::kOk;
  }
  if (errno == EAGAIN || errno == ENOBUFS) return DeviceStatus::kTimeout;  // transmit queue full
  link_lost();                                                             // EPIPE, ENETDOWN, ENODEV...
  return DeviceStatus::kDisconnected;
}

void CanRobot::take(const can_frame& f) {
  ++counters_.frames_in;
  if ((f.can_id & CAN_ERR_FLAG) != 0) {
    ++counters_.error_frames;
    const canid_t cls = f.can_id & CAN_ERR_MASK;
    if ((cls & CAN_ERR_BUSOFF) != 0) bus_off_ = true;
    if ((cls & CAN_ERR_CRTL) != 0 && f.can_dlc >= 2) {
      if ((f.data[1] & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE)) != 0) error_passive_ = true;
      if ((f.data[1] & CAN_ERR_CRTL_ACTIVE) != 0) error_passive_ = false;
    }
    if ((cls & CAN_ERR_RESTARTED) != 0) {
      bus_off_ = false;
      latched_ |= kCanControllerRestarted;
    }
    const std::int64_t t = now_ns();
    if (t - flood_window_start_ns_ > 1'000'000'000) {
      flood_window_start_ns_ = t;
      flood_window_count_ = 0;
    }
    if (++flood_window_count_ > options_.error_frames_per_s_limit) latched_ |= kCanErrorFlood;
    return;
  }
  if ((f.can_id & CAN_EFF_FLAG) != 0) return;
  const canid_t id = f.can_id & CAN_SFF_MASK;
  const canid_t n = static_cast<canid_t>(options_.node_id);
  if (id == can::kHeartbeat + n && f.can_dlc >= 1) {
    ++counters_.heartbeats;
    last_heartbeat_ns_ = now_ns();
    robot_state_ = f.data[0];
    if (robot_state_ == can::kStateBootUp) {
      latched_ |= kCanRobotRestarted;
      enabled_ = false;
    }
  } else if (id == can::kAcknowledge + n && f.can_dlc >= 2) {
    if (f.data[0] == sequence_) {
      ack_fresh_ = true;
      ack_result_ = f.data[1];
    }
  } else if (id == can::kStatus + n && f.can_dlc >= 4) {
    if (f.data[0] == token_) {
      status_fresh_ = true;
      travel_frames_ = 0;
      status_fault_ = f.data[2];
      status_flags_ = f.data[3];
    }
  } else if (id >= can::kPositionFirst + n && id < can::kPositionFirst + n + 6 && f.can_dlc == 8 &&
             status_fresh_) {
    const int k = static_cast<int>(id - can::kPositionFirst - n);
    if (k < 3)
      can::decode_travel_frame(f, k, &position_);
    else
      can::decode_travel_frame(f, k - 3, &target_);
    travel_frames_ |= 1 << k;
  }
}

void CanRobot::pump() {
  can_frame f;
  for (int i = 0; i < kMaxFramesPerPump && fd_ >= 0; ++i) {
    const ssize_t n = ::recv(fd_, &f, sizeof f, MSG_DONTWAIT);
    if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
      // End of file (the bridge, or the robot at a socket's other end, went away) or the
      // interface's error.
      link_lost();
      break;
    }
    if (n != ssize_t(sizeof f)) break;
    link_regained();
    take(f);
  }
  if (last_heartbeat_ns_ != 0 && double(now_ns() - last_heartbeat_ns_) > options_.heartbeat_timeout_s * 1e9)
    latched_ |= kCanHeartbeatMissing;
  seen_ |= faults();
}

std::uint32_t CanRobot::conditions() const {
  return (bus_off_ ? kCanBusOff : 0u) | (error_passive_ ? kCanErrorPassive : 0u);
}

bool CanRobot::wait(Deadline deadline, bool (CanRobot::*done)() const) {
  for (;;) {
    pump();
    if ((this->*done)()) return true;
    const auto left = deadline - std::chrono::steady_clock::now();
    if (left <= Deadline::duration::zero()) return false;
    const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(left).count();
    const timespec timeout{static_cast<time_t>(ns / 1'000'000'000), static_cast<long>(ns % 1'000'000'000)};
    pollfd p{fd_, POLLIN, 0};
    ::ppoll(&p, 1, &timeout, nullptr);
  }
}

DeviceStatus CanRobot::command(const tracking::Vector6d& correction, Deadline deadline) {
  if (!linked()) return DeviceStatus::kDisconnected;
  pump();
  if (fd_ < 0) return DeviceStatus::kDisconnected;
  if (faults() != 0) return DeviceStatus::kRefused;
  can_frame translation, rotation;
  const auto next = static_cast<std::uint8_t>(sequence_ + 1);
  if (!can::encode_correction(correction, options_.node_id, next, &translation, &rotation))
    return DeviceStatus::kRefused;
  if (!enabled_) {  // after open, hold or a restart: the robot moves only once told to
    can_frame control = can::make_frame(can::kControl, options_.node_id, 2);
    control.data[0] = can::kControlEnable;
    if (const DeviceStatus s = send(control); s != DeviceStatus::kOk) return s;
    enabled_ = true;
  }
  sequence_ = next;
  ack_fresh_ = false;
  if (const DeviceStatus s = send(translation); s != DeviceStatus::kOk) return s;
  if (const DeviceStatus s = send(rotation); s != DeviceStatus::kOk) return s;
  if (!wait(deadline, &CanRobot::ack_arrived)) {
    ++counters_.timeouts;
    return DeviceStatus::kTimeout;
  }
  if (ack_result_ != can::kAckAccepted) {
    ++counters_.refused;
    return DeviceStatus::kFault;
  }
  return DeviceStatus::kOk;
}

DeviceStatus CanRobot::readback(ActuatorState* state, Deadline deadline) {
  if (!linked()) return DeviceStatus::kDisconnected;
  pump();
  if (fd_ < 0) return DeviceStatus::kDisconnected;
  if (faults() != 0) {
    state->fault = true;
    return DeviceStatus::kFault;
  }
  can_frame request = can::make_frame(can::kReadbackRequest, options_.node_id, 1);
  request.data[0] = ++token_;
  status_fresh_ = false;
  travel_frames_ = 0;
  if (const DeviceStatus s = send(request); s != DeviceStatus::kOk) return s;
  if (!wait(deadline, &CanRobot::readback_complete)) {
    ++counters_.timeouts;
    return DeviceStatus::kTimeout;
  }
  if (status_fault_ != 0) latched_ |= kCanRobotFault;
  seen_ |= faults();
  state->position = position_;
  state->target = target_;
  state->moving = (status_flags_ & can::kFlagMoving) != 0;
  state->fault = faults() != 0;
  return state->fault ? DeviceStatus::kFault : DeviceStatus::kOk;
}

void CanRobot::hold() {
  enabled_ = false;
  if (fd_ < 0) return;
  can_frame control = can::make_frame(can::kControl, options_.node_id, 2);
  control.data[0] = can::kControlHold;
  (void)send(control);
  pump();
  // The operator's resume follows; what was an event is acknowledged by this hold.
  latched_ &= ~std::uint32_t(kCanControllerRestarted | kCanRobotRestarted | kCanRobotFault);
  if (double(now_ns() - last_heartbeat_ns_) <= options_.heartbeat_timeout_s * 1e9)
    latched_ &= ~std::uint32_t(kCanHeartbeatMissing);
  if (flood_window_count_ <= options_.error_frames_per_s_limit) latched_ &= ~std::uint32_t(kCanErrorFlood);
}

void CanRobot::set_beam_permit(bool permit) {
  if (fd_ < 0) return;
  can_frame f = can::make_frame(can::kBeamPermit, options_.node_id, 2);
  f.data[0] = permit ? 1 : 0;
  f.data[1] = permit_counter_++;
  (void)send(f);
}

}  // namespace lftrack::drivers
