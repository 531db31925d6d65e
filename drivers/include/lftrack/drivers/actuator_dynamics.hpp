#pragma once
// What the host assumes of the actuator that moves the patient, whatever its kind: how long a
// command takes to start the motion, how fast it moves and how far it may travel. The scene's
// `actuator` section gives them for every type that moves (modbus, can, virtual): the motion
// predictor's default look-ahead is the loop's period plus the latency (loop.lookahead_s
// overrides it), the session warns when the largest allowed correction (safety.max_total_mm) at
// these speeds takes longer than the beam may wait, and the simulator's virtual couch and the
// served twins move exactly so.

namespace lftrack::drivers {

struct ActuatorDynamics {
  double latency_s = 0.15;      // command to start of motion, s
  double max_speed_mm_s = 20;   // along the straight line to the target
  double max_speed_deg_s = 10;  // rotation angle rate
  double range_mm = 50;         // per translation axis, from zero
  double range_deg = 10;        // per rotation component, from zero
};

}  // namespace lftrack::drivers
