#pragma once
// `lftrack bench register`: registration speed and accuracy on a scene, all in one run:
// - cold: the scene's plan from starts at an initial mean TRE of up to `cold_max_initial_mm`;
// - warm: tracking a moving patient, each frame pair after a motion of up to
//   `warm_translation_mm` and `warm_rotation_deg` (per axis), started from the previous result
//   with the warm plan ("warm" unless asked otherwise), timed per registration;
// - renderers: the same cold registrations with light-field and with Siddon DRRs inside the
//   registration (frames always ray-cast), mean TRE of each.

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "lftrack/session/scene.hpp"

namespace lftrack::studies {

struct RegistrationBenchOptions {
  // The cold plan (empty: the scene's tracking.plan) and the warm plan (a registration_plan name).
  std::string cold_plan;
  std::string warm_plan = "warm";
  int cold_runs = 20;
  double cold_max_initial_mm = 8;
  int warm_runs = 100;
  double warm_translation_mm = 2;
  double warm_rotation_deg = 2;
  int renderer_runs = 4;  // Siddon registrations take tens of seconds each; 0 skips the comparison
  std::uint64_t seed = 1;
};

struct TimedRegistrations {
  int runs = 0;
  double median_ms = 0, p95_ms = 0, max_ms = 0;
  double mean_tre_mm = 0, max_tre_mm = 0;  // of every run's mean TRE
  double success_rate = 0;                 // mean TRE < 2 mm
  double median_evaluations = 0;
  // Per pass of the plan: the median time (its references included) and evaluations, over the
  // runs that reached it.
  struct Pass {
    double median_ms = 0, median_evaluations = 0;
  };
  std::vector<Pass> passes;
};

struct RegistrationBenchReport {
  std::string scene, plan, warm_plan, similarity;
  int threads = 0;
  TimedRegistrations cold, warm;
  TimedRegistrations lightfield_inside, siddon_inside;  // same starts and frames
};

Result<RegistrationBenchReport> run_registration_benchmark(const session::PreparedScene& scene,
                                                           const RegistrationBenchOptions& options,
                                                           tracking::ThreadPool* pool);
nlohmann::json to_json(const RegistrationBenchReport& report);

}  // namespace lftrack::studies
