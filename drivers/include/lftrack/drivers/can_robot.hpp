#pragma once
// The beam robot over SocketCAN (CAN_RAW), frame layout in can_robot_protocol.hpp.
//
// The same read and write code runs on a CAN_RAW socket bound to an interface (can0, vcan0) or
// on any connected socket that carries `struct can_frame` records, such as one end of a
// socketpair(AF_UNIX, SOCK_SEQPACKET) with the virtual robot (sim/virtual_robot.hpp) on the
// other: this machine's kernel has no CAN support at all.
//
// Safety: these conditions make every cycle call return kFault, so the loop HOLDs (read-back)
// or stops (command):
//   bus-off, error-passive          while they last (until "restarted" or "error active")
//   CAN controller restarted        latched until hold()
//   robot restarted (boot-up)       latched until hold(); the robot is then pre-operational and
//                                   moves only after the next command re-enables it
//   missing heartbeat               latched until hold() with the heartbeat back
//   error-frame flood               latched until hold() with the rate back under the limit
// hold() is what the loop calls on entering HOLD, and leaving HOLD takes an operator resume, so
// nothing resumes motion silently after a restart. Cycle calls read at most a bounded number of
// frames, so a flood cannot keep the cycle past its deadline.

#include <linux/can.h>

#include <cstdint>
#include <string>

#include "lftrack/drivers/actuator.hpp"

namespace lftrack::drivers {

struct CanRobotOptions {
  std::string interface = "can0";  // CAN_RAW on this interface (unless a socket is given)
  int node_id = 1;                 // 1..15
  double heartbeat_timeout_s = 0.3;
  int error_frames_per_s_limit = 50;  // more is a flood
  double open_timeout_s = 2.0;        // for the first heartbeat
  // Non-empty: the robot is reached through a CAN bridge process listening on this Unix socket
  // (SOCK_SEQPACKET, one struct can_frame per datagram; `lftrack serve robot --socket PATH`)
  // instead of `interface`. A bridge that goes away is a disconnection: the driver tries again
  // every reconnect_interval_s from the cycle (a non-blocking connect on a local socket), and a
  // link made again counts as a restarted robot (kCanRobotRestarted: nothing moves until a hold,
  // which the operator's resume follows).
  std::string bridge_path;
  double reconnect_interval_s = 0.2;
};

// Conditions, as bits of CanRobot::faults().
enum CanRobotFault : std::uint32_t {
  kCanBusOff = 1u << 0,
  kCanErrorPassive = 1u << 1,
  kCanControllerRestarted = 1u << 2,
  kCanRobotRestarted = 1u << 3,
  kCanHeartbeatMissing = 1u << 4,
  kCanErrorFlood = 1u << 5,
  kCanRobotFault = 1u << 6,  // the robot's status reports a fault
};
std::string describe_can_faults(std::uint32_t faults);

// disconnects: the link lost (end of file or an error on the socket: a bridge or a robot at a
// socket's other end gone, a CAN interface down), once per loss; reconnects: a link made again
// (a bridge dialled again, a CAN interface whose frames flow again). As the Modbus couch's.
struct CanRobotCounters {
  std::int64_t frames_in = 0, frames_out = 0, error_frames = 0, heartbeats = 0, timeouts = 0, refused = 0,
               disconnects = 0, reconnects = 0;
};

class CanRobot final : public Actuator {
 public:
  explicit CanRobot(CanRobotOptions options);
  // Runs over `socket_fd` (connected, carrying struct can_frame records); takes ownership.
  CanRobot(CanRobotOptions options, int socket_fd);
  ~CanRobot() override;
  CanRobot(const CanRobot&) = delete;
  CanRobot& operator=(const CanRobot&) = delete;

  // Outside the cycle: opens the interface (CAN_RAW, error frames enabled with
  // CAN_RAW_ERR_FILTER, a filter for the robot's identifiers) and waits for a heartbeat.
  Status open() override;
  DeviceStatus command(const tracking::Vector6d& correction, Deadline deadline) override;
  DeviceStatus readback(ActuatorState* state, Deadline deadline) override;
  void hold() override;
  void set_beam_permit(bool permit) override;
  void close() override;

  std::uint32_t faults() const { return conditions() | latched_; }  // now
  std::uint32_t faults_seen() const { return seen_; }               // every fault since construction
  const CanRobotCounters& counters() const { return counters_; }

 private:
  std::uint32_t conditions() const;
  void pump();  // reads what is waiting, at most kMaxFramesPerPump
  void take(const can_frame& frame);
  bool wait(Deadline deadline, bool (CanRobot::*done)() const);
  bool ack_arrived() const { return ack_fresh_; }
  bool readback_complete() const { return status_fresh_ && travel_frames_ == 0x3F; }
  DeviceStatus send(const can_frame& frame);
  std::int64_t now_ns() const;
  Status connect_bridge();  // bridge_path: a connected, non-blocking SOCK_SEQPACKET socket in fd_
  void link_lost();         // counted once per loss; a bridge's or a given socket's fd_ closed
  void link_regained();     // counted where the link was lost
  bool linked();            // fd_ open, or (bridge) opened again now that the interval has passed

  CanRobotOptions options_;
  int fd_ = -1;
  bool given_socket_ = false;
  std::int64_t last_connect_attempt_ns_ = 0;
  CanRobotCounters counters_;
  std::uint32_t latched_ = 0;
  std::uint32_t seen_ = 0;  // faults() at every look, or-ed
  bool link_up_ = false;
  bool bus_off_ = false, error_passive_ = false;
  std::int64_t last_heartbeat_ns_ = 0;
  std::uint8_t robot_state_ = 0;
  std::int64_t flood_window_start_ns_ = 0;
  int flood_window_count_ = 0;
  bool enabled_ = false;  // we enabled it since the last hold or restart
  std::uint8_t sequence_ = 0, token_ = 0, permit_counter_ = 0;
  bool ack_fresh_ = false;
  std::uint8_t ack_result_ = 0;
  bool status_fresh_ = false;
  int travel_frames_ = 0;  // bits: which of the six read-back frames arrived
  std::uint8_t status_fault_ = 0, status_flags_ = 0;
  tracking::Vector6d position_ = tracking::Vector6d::Zero(), target_ = tracking::Vector6d::Zero();
};

}  // namespace lftrack::drivers
