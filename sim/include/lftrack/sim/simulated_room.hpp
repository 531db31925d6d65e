#pragma once
// The simulated treatment room of the closed loop: a patient who lies with a set-up error and
// moves (patient_motion.hpp), on a virtual couch that applies the loop's corrections
// (virtual_couch.hpp). It knows the truth the loop estimates: where the anatomy is at any time.
//
// Time: the room's clock starts (t = 0) at the first loop time it is advanced to; loop times
// are CLOCK_MONOTONIC nanoseconds (or the loop's simulated clock). The loop's thread advances
// the room and reads the truth; in hardware-in-the-loop runs the virtual couch server's thread
// drives the couch (couch_device()). Every public member locks the room, so both may.
//
// True pose: T(t) = M(couch(t)) * A(motion(t)) * A(setup_error) * T_nominal, where A(d) is the
// rigid motion of delta d about the registration origin (pose.hpp) and M(q) = X E(q) X^-1 the
// room motion of couch position q for a couch mounted at X = T_room_from_couch
// (calib/couch_calibration.hpp). The ideal couch, X = Translation(origin), gives M = A.
// The couch cancels the patient's offset when M(couch) = (A(motion) A(setup_error))^-1.

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/sim/patient_motion.hpp"
#include "lftrack/sim/room_link.hpp"
#include "lftrack/sim/virtual_couch.hpp"

namespace lftrack::sim {

struct SimulatedRoomSpec {
  tracking::Pose nominal_T_room_from_ct = tracking::Pose::Identity();
  Eigen::Vector3d origin_room_mm = Eigen::Vector3d::Zero();
  tracking::Vector6d setup_error = tracking::Vector6d::Zero();  // mm, rad
  sim_spec::PatientMotionSpec motion;
  VirtualCouchSpec couch;
  // Where the couch is mounted: its rotation centre and translation axes in the room. Unset:
  // the ideal couch, axes along the room's, rotating about the registration origin.
  std::optional<Eigen::Isometry3d> couch_T_room_from_couch;
  // The residual is measured over a cube of this edge at the registration origin.
  double residual_box_mm = 40;
  // Set: the couch is another process's (`lftrack serve couch --room FILE`): the patient is
  // where that couch has moved them, read from its room link; the room's own couch is unused.
  std::shared_ptr<const RoomLinkReader> couch_link;
};

class SimulatedRoom {
 public:
  explicit SimulatedRoom(const SimulatedRoomSpec& spec);

  // Moves the room to loop time `t_ns` (never backwards; the first call sets t = 0).
  void advance_to_ns(std::int64_t t_ns);
  double time_s() const;
  // The loop time of t = 0 (the first advance_to_ns), or -1 before it.
  std::int64_t epoch_ns() const;
  double time_s_at(std::int64_t t_ns) const;

  // The anatomy's pose now, and the patient's own offset (set-up error and motion) as one delta.
  tracking::Pose true_T_room_from_ct() const;
  tracking::Pose patient_T_room_from_ct() const;  // without the couch
  // The anatomy's pose as a pair exposed at `exposure_ns` (CLOCK_MONOTONIC) shows it: the patient
  // at the room's time (advance_to_ns(exposure_ns) first), the couch of a room link where it was
  // at exposure_ns (however late this is asked), a couch in process where it is.
  tracking::Pose true_T_room_from_ct_at_exposure(std::int64_t exposure_ns) const;
  // The true residual now: mean displacement of the 27 points of a 3 x 3 x 3 grid over the
  // residual box between where the anatomy is and where the plan has it (mm).
  double residual_mm() const;
  // The target's true offset now, at the registration origin, in the room frame: where the
  // anatomy has the origin minus where the plan has it (mm), then the rotation vector that takes
  // the plan's orientation to the anatomy's (rad).
  tracking::Vector6d target_residual() const;

  // The couch as the loop sees it in process: a command takes effect as if sent at its deadline
  // (the latest the cycle may send it), so a run is deterministic whatever the host's speed.
  drivers::Actuator& couch_actuator() { return actuator_; }
  // The couch as a device behind a protocol (the virtual couch server): commands take effect at
  // the room's current time. A hardware-in-the-loop run calls advance_for_command() with the
  // cycle's deadline before its driver sends, which gives the same timing as couch_actuator().
  drivers::Actuator& couch_device() { return device_; }
  void advance_for_command(drivers::Deadline deadline);
  tracking::Vector6d couch_position() const;
  const SimulatedRoomSpec& spec() const { return spec_; }
  // The couch's mounting: the spec's, or the ideal couch's.
  Eigen::Isometry3d T_room_from_couch() const;

 private:
  // The room's couch as an Actuator: `clocked` moves the room on to a command's deadline first
  // (couch_actuator()); otherwise commands act at the room's current time (couch_device()).
  class CouchActuator final : public drivers::Actuator {
   public:
    CouchActuator(SimulatedRoom& room, bool clocked) : room_(room), clocked_(clocked) {}
    Status open() override { return {}; }
    drivers::DeviceStatus command(const tracking::Vector6d& correction, drivers::Deadline deadline) override;
    drivers::DeviceStatus readback(drivers::ActuatorState* state, drivers::Deadline deadline) override;
    void hold() override;
    void close() override {}

   private:
    SimulatedRoom& room_;
    bool clocked_;
  };
  void advance_locked(std::int64_t t_ns);
  void advance_for_command_locked(drivers::Deadline deadline);
  tracking::Pose true_locked() const;
  tracking::Pose true_locked_with(const tracking::Vector6d& couch_position) const;
  tracking::Vector6d couch_position_locked() const;
  tracking::Pose patient_locked() const;

  mutable std::mutex mutex_;
  SimulatedRoomSpec spec_;
  VirtualCouch couch_;
  CouchActuator actuator_{*this, true};
  CouchActuator device_{*this, false};
  bool started_ = false;
  std::int64_t epoch_ns_ = 0;
};

}  // namespace lftrack::sim
