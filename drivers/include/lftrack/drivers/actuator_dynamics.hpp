#pragma once
// What the host assumes of the actuator that moves the patient, whatever its kind: how long a
// command takes to start the motion, how fast it moves and how far it may travel. The scene's
// `actuator` section gives them for every actuator type: the motion predictor looks ahead by the
// latency, the session checks that the largest correction fits the safety limits at these speeds,
// and the simulator's virtual couch and robot are built to move exactly so.

namespace lftrack::drivers {

struct ActuatorDynamics {
  double latency_s = 0.15;      // command to start of motion, s
  double max_speed_mm_s = 20;   // along the straight line to the target
  double max_speed_deg_s = 10;  // rotation angle rate
  double range_mm = 50;         // per translation axis, from zero
  double range_deg = 10;        // per rotation component, from zero
};

}  // namespace lftrack::drivers
