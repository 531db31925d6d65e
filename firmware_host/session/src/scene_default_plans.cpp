#include "lftrack/host/scene_default_plans.hpp"

namespace lftrack::host {

bool frames_are_ideal(const Scene& scene) {
  for (const auto& d : scene.detectors)
    if (d.frames.kind != "sim") return false;
  return scene.sim.physics.ideal();
}

DefaultPlans default_plans(const Scene& scene) {
  if (frames_are_ideal(scene))
    return {"papers", "quadratic", "warm", "ideal simulated frames (sim.physics: ideal)"};
  const std::string kind = scene.detectors.empty() ? std::string("sim") : scene.detectors.front().frames.kind;
  const std::string because = kind == "sim" ? "simulated frames with sim.physics " + scene.sim.physics_name
                              : kind == "replay" ? std::string("archived frames")
                                                 : "frames from " + kind + " devices";
  return {"robust", "robust", "warm-robust", because};
}

}  // namespace lftrack::host
