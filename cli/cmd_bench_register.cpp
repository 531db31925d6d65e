// `lftrack bench register`: cold and warm registration times and TRE, light field against
// Siddon inside the registration.

#include <cstdio>

#include "cli_commands.hpp"
#include "lftrack/studies/registration_benchmark.hpp"
#include "lftrack/tracking/registration.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using studies::RegistrationBenchOptions;
using studies::run_registration_benchmark;
using studies::TimedRegistrations;

Command add_bench_register_command(CLI::App* parent) {
  auto* app = parent->add_subcommand("register", "Cold and warm registration time and TRE on synthetic frames");
  struct Options {
    SceneOptions scene;
    RegistrationBenchOptions bench;
    bool json = false;
  };
  auto o = std::make_shared<Options>();
  add_scene_options(app, &o->scene);
  std::string plans;
  for (const auto& name : tracking::registration_plan_names()) plans += (plans.empty() ? "" : ", ") + name;
  app->add_option("--plan", o->bench.cold_plan, "Cold registration plan (default: the scene's tracking.plan; " + plans + ")")
      ->check(CLI::IsMember(tracking::registration_plan_names()));
  app->add_option("--warm-plan", o->bench.warm_plan, "Warm registration plan (" + plans + ")")
      ->capture_default_str()
      ->check(CLI::IsMember(tracking::registration_plan_names()));
  // The cold runs make the problems, so at least one; --warm 0 times the cold runs alone.
  app->add_option("--cold", o->bench.cold_runs, "Cold registrations")->capture_default_str()->check(CLI::Range(1, 100000));
  app->add_option("--warm", o->bench.warm_runs, "Warm (tracking) registrations (0 skips)")
      ->capture_default_str()
      ->check(CLI::Range(0, 100000));
  app->add_option("--siddon-runs", o->bench.renderer_runs,
                  "Cold problems repeated with Siddon DRRs inside the registration (slow; 0 skips)")
      ->capture_default_str()
      ->check(CLI::Range(0, 100000));
  app->add_option("--seed", o->bench.seed, "Seed")->check(seed_value())->capture_default_str();
  app->add_flag("--json", o->json, "Print the report as JSON on stdout");
  return [o]() -> Status {
    tracking::ThreadPool pool(o->scene.threads);
    auto prepared = load_prepared_scene(o->scene, &pool);
    if (!prepared.ok()) return prepared.status();
    auto report = run_registration_benchmark(*prepared, o->bench, &pool);
    if (!report.ok()) return report.status();
    if (o->json) {
      std::printf("%s\n", to_json(*report).dump(2).c_str());
      return {};
    }
    auto line = [](const char* what, const TimedRegistrations& t) {
      if (t.runs == 0) {
        std::printf("%-28s %5d  not run\n", what, t.runs);
        return;
      }
      std::printf("%-28s %5d %9.1f %9.1f %9.1f %9.3f %9.3f %7.1f%% %7.0f\n", what, t.runs, t.median_ms, t.p95_ms,
                  t.max_ms, t.mean_tre_mm, t.max_tre_mm, 100 * t.success_rate, t.median_evaluations);
      for (std::size_t p = 0; p < t.passes.size(); ++p)
        std::printf("  pass %zu%-20s %5s %9.1f %9s %9s %9s %9s %8s %7.0f\n", p + 1, "", "", t.passes[p].median_ms, "",
                    "", "", "", "", t.passes[p].median_evaluations);
    };
    std::printf("%s, plan %s, warm plan %s, %s, %d threads\n", report->scene.c_str(), report->plan.c_str(),
                report->warm_plan.c_str(), report->similarity.c_str(), report->threads);
    std::printf("%-28s %5s %9s %9s %9s %9s %9s %8s %7s\n", "", "runs", "median ms", "p95 ms", "max ms", "mean TRE",
                "max TRE", "success", "evals");
    line("cold", report->cold);
    line("warm (2 mm / 2 deg moves)", report->warm);
    if (report->siddon_inside.runs > 0) {
      line("cold, light field inside", report->lightfield_inside);
      line("cold, Siddon inside", report->siddon_inside);
    }
    return {};
  };
}

}  // namespace lftrack::cli
