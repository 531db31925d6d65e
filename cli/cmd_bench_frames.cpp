// `lftrack bench frames`: the simulator's frame pairs, Siddon against light fields, side by side.

#include <cstdio>

#include "cli_commands.hpp"
#include "lftrack/studies/frame_benchmark.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using studies::FrameBenchOptions;
using studies::run_frame_benchmark;

Command add_bench_frames_command(CLI::App* parent) {
  auto* app = parent->add_subcommand(
      "frames", "Time the simulator's frame pairs, Siddon against light fields, as the simulated detectors render them");
  struct Options {
    SceneOptions scene;
    FrameBenchOptions bench;
    std::string lf_dir;
    bool json = false;
  };
  auto o = std::make_shared<Options>();
  add_scene_options(app, &o->scene);
  app->add_option("--pairs", o->bench.pairs, "Timed frame pairs per renderer, at poses across the envelope")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000000));
  app->add_option("--seed", o->bench.seed, "Pose and noise seed")->check(seed_value())->capture_default_str();
  app->add_option("--lf-dir", o->lf_dir,
                  "Light-field folder (default out/lightfields/<scene>); the simulator's fields are in its "
                  "sim-frames folder, built there when missing");
  app->add_flag("--json", o->json, "Print the report as JSON on stdout");
  return [o]() -> Status {
    tracking::ThreadPool pool(o->scene.threads);
    auto prepared = load_prepared_scene(o->scene, &pool);
    if (!prepared.ok()) return prepared.status();
    FrameBenchOptions bench = o->bench;
    bench.light_field_dir = o->lf_dir;
    auto report = run_frame_benchmark(*prepared, bench, &pool);
    if (!report.ok()) return report.status();
    if (o->json) {
      std::printf("%s\n", to_json(*report).dump(2).c_str());
      return {};
    }
    std::printf("%s: %d frame pairs per renderer on one thread (the simulated detectors' own); physics: %s\n",
                report->scene.c_str(), report->pairs, report->physics.c_str());
    std::printf("%-12s %10s %10s %10s %10s %10s %10s %14s %12s %14s\n", "renderer", "setup s", "pixels", "pair ms",
                "p95 ms", "min ms", "x Siddon", "NCC vs Siddon", "NCC min", "whole pair ms");
    for (const auto& r : report->renderers)
      std::printf("%-12s %10.1f %10d %10.2f %10.2f %10.2f %10.1f %14.6f %12.6f %14.2f\n", r.renderer.c_str(), r.setup_s,
                  r.exposed_pixels, r.pair_ms_median, r.pair_ms_p95, r.pair_ms_min, r.speedup_vs_siddon,
                  r.ncc_vs_siddon, r.ncc_min_vs_siddon, r.whole_pair_ms_median);
    std::printf("pixels: both views' exposed windows (Siddon's ROI and a 16-pixel margin; a light field's ROI); NCC: "
                "expected counts over the ROI windows; whole pair: the same pair over the whole detectors, as the "
                "loop exposes them (the rest of each detector coarser, by Siddon), timed beside it\n");
    return {};
  };
}

}  // namespace lftrack::cli
