#pragma once
// The registration plans a scene runs when it names none (docs/scenes.md, "Registration plans").
//
// Every frame a real detector gives carries scatter, a polyenergetic spectrum, the panel's own
// response and anatomy that moved since the CT. Quadratic MI, tuned on ideal DRRs, is pulled by
// all of them (on an independent skull check 0.374 mm against the robust plan's 0.060 mm), so a
// scene gets the robust plans unless its frames are ideal: simulated, with `sim.physics: ideal`.
// A scene that names a plan keeps it.

#include <string>

#include "lftrack/session/scene.hpp"

namespace lftrack::session {

struct DefaultPlans {
  std::string plan;        // tracking.plan (`lftrack register`)
  std::string align_plan;  // loop.align_plan
  std::string track_plan;  // loop.track_plan
  std::string because;     // why these, for a log line: "ideal simulated frames", "frames from gige devices"
};

// Whether the scene's frames are ideal: every detector simulated, and sim.physics ideal.
bool frames_are_ideal(const Scene& scene);
DefaultPlans default_plans(const Scene& scene);
// Sets the plans the scene did not name (scene.defaulted_plans) to `defaults`.
void apply_default_plans(const DefaultPlans& defaults, Scene* scene);
// The plans for frames from an archive (`lftrack replay --sequence` on a scene whose detectors
// are simulated: the archive may hold any detector's frames).
DefaultPlans archived_frame_plans();
// "align robust (the scene's), track warm-robust (the default for ...)": the loop's plans, each
// said to be named or chosen, for the run's log.
std::string describe_loop_plans(const Scene& scene);

}  // namespace lftrack::session
