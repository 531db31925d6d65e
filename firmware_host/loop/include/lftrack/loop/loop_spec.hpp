#pragma once
// The loop's settings as a scene's `loop` section declares them (DESIGN.md, "One cycle"): the
// period, the budgets, the registration plans, the prediction and the real-time set-up. Parsed
// by the session (scene_loop_parser.cpp); read by the loop.

#include <optional>
#include <string>
#include <vector>

#include "lftrack/loop/imaging_on_demand.hpp"

namespace lftrack::loop {

// loop: the real-time cycle (DESIGN.md, "One cycle").
struct RealtimeSpec {
  bool enforce = false;   // enforce: refuse to start without mlockall, SCHED_FIFO and affinity
  int priority = 80;      // SCHED_FIFO priority of the cycle's thread (1..99)
  std::vector<int> cpus;  // the cycle's CPUs; empty: leave the affinity alone
};
struct LoopSpec {
  double period_ms = 100;
  double registration_budget_ms = 60;    // the warm registration's wall-time budget per cycle (real clock only)
  double acquire_timeout_ms = 40;        // how long a cycle waits for its frame pair
  std::string align_plan = "quadratic";  // the cold, wide-range registration before tracking
  std::string track_plan = "warm";       // each cycle's registration, from the last pose
  // Prediction of the patient's own motion over the latency from frame to couch motion: a
  // polynomial of `prediction_order` (1 or 2) fitted to the last `prediction_cycles` estimates,
  // extrapolated by `lookahead_s` (unset: one period plus the actuator's latency).
  // prediction_cycles < 2: no prediction.
  std::optional<double> lookahead_s;
  int prediction_cycles = 8;
  int prediction_order = 2;
  // Whether rotations are extrapolated too; by default only translations are, and a rotation is
  // its newest estimate (motion_predictor.hpp says why). For a scene whose target really rotates
  // with its breathing.
  bool predict_rotations = false;
  // The registration verdict on tracking cycles (issue 52): unset follows the scene (judged where
  // the scene is commissioned: its floors were measured on tracking registrations).
  std::optional<bool> judge_tracking;
  RealtimeSpec realtime;
  // tracking.imaging: a pair every cycle, or sparse pairs and a surrogate's correlation model.
  ImagingSpec imaging;
};

}  // namespace lftrack::loop
