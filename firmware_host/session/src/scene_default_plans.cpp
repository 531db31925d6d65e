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

void apply_default_plans(const DefaultPlans& defaults, Scene* scene) {
  Scene::DefaultedPlans& d = scene->defaulted_plans;
  if (d.plan) scene->registration.plan = defaults.plan;
  if (d.align) scene->loop.align_plan = defaults.align_plan;
  if (d.track) scene->loop.track_plan = defaults.track_plan;
  d.because = d.plan || d.align || d.track ? defaults.because : std::string();
}

DefaultPlans archived_frame_plans() {
  return {"robust", "robust", "warm-robust", "archived frames (lftrack replay --sequence)"};
}

std::string describe_loop_plans(const Scene& scene) {
  const Scene::DefaultedPlans& d = scene.defaulted_plans;
  const auto one = [&](const char* what, const std::string& plan, bool defaulted) {
    return std::string(what) + " " + plan +
           (defaulted ? " (the default for " + d.because + ")" : std::string(" (the scene's)"));
  };
  return one("align", scene.loop.align_plan, d.align) + ", " + one("track", scene.loop.track_plan, d.track);
}

}  // namespace lftrack::host
