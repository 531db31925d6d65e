#include "lftrack/session/scene_default_plans.hpp"

#include "lftrack/session/scene_devices.hpp"

namespace lftrack::session {
namespace {

DefaultPlans robust_plans(std::string because) {
  return {"robust", "robust", "warm-robust", std::move(because)};
}

}  // namespace

// Every detector of a scene takes its frames from one kind (the parser refuses a mix).
bool frames_are_ideal(const Scene& scene) {
  return frames_are_simulated(scene) && scene.sim.physics.ideal();
}

DefaultPlans default_plans(const Scene& scene) {
  if (frames_are_ideal(scene))
    return {"papers", "quadratic", "warm", "ideal simulated frames (sim.physics: ideal)"};
  const std::string kind = scene.detectors.empty() ? std::string("sim") : scene.detectors.front().frames.kind;
  const std::string because = kind == "sim" ? "simulated frames with sim.physics " + scene.sim.physics_name
                              : kind == "replay" ? std::string("archived frames")
                                                 : "frames from " + kind + " devices";
  return robust_plans(because);
}

void apply_default_plans(const DefaultPlans& defaults, Scene* scene) {
  Scene::DefaultedPlans& d = scene->defaulted_plans;
  if (d.plan) scene->registration.plan = defaults.plan;
  if (d.align) scene->loop.align_plan = defaults.align_plan;
  if (d.track) scene->loop.track_plan = defaults.track_plan;
  d.because = d.plan || d.align || d.track ? defaults.because : std::string();
}

DefaultPlans archived_frame_plans() {
  return robust_plans("archived frames (lftrack replay --sequence)");
}

std::string describe_loop_plans(const Scene& scene) {
  const Scene::DefaultedPlans& d = scene.defaulted_plans;
  const auto one = [&](const char* what, const std::string& plan, bool defaulted) {
    return std::string(what) + " " + plan +
           (defaulted ? " (the default for " + d.because + ")" : std::string(" (the scene's)"));
  };
  return one("align", scene.loop.align_plan, d.align) + ", " + one("track", scene.loop.track_plan, d.track);
}

}  // namespace lftrack::session
