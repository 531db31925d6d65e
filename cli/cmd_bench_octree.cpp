// `lftrack bench octree`: paper 3's compression table for a CT.

#include <cstdio>

#include "cli_commands.hpp"
#include "lftrack/session/progress_bar.hpp"
#include "lftrack/studies/octree_benchmark.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "lftrack/tracking/volume_io.hpp"

namespace lftrack::cli {

using session::ProgressBar;

using studies::OctreeBenchOptions;
using studies::run_octree_benchmark;
namespace {

struct BenchOctreeOptions {
  SceneOptions scene;
  OctreeBenchOptions bench;
  bool json = false;
};

Status run(const BenchOctreeOptions& o) {
  tracking::MuVolume mu;
  std::string name;
  if (!o.scene.ct.empty()) {
    auto ct = tracking::read_ct(o.scene.ct);
    if (!ct.ok()) return ct.status();
    mu = tracking::to_attenuation(*ct);
    name = o.scene.ct;
  } else {
    tracking::ThreadPool pool(o.scene.threads);
    auto prepared = load_prepared_scene(o.scene, &pool);
    if (!prepared.ok()) return prepared.status();
    mu = *prepared->mu;
    name = prepared->scene.ct.path;
  }
  ProgressBar bar("octree benchmark");
  auto report = run_octree_benchmark(mu, name, o.bench, [&](double f) { bar.update(f); });
  if (!report.ok()) return report.status();
  bar.finish();
  if (o.json) {
    std::printf("%s\n", to_json(*report).dump(2).c_str());
    return {};
  }
  std::printf(
      "CT %s: %lld voxels (%.1f MB as float); %d x %d DRRs of the whole CT, %d poses x 2 views, "
      "1 thread; Siddon %.1f ms\n",
      report->ct.c_str(), static_cast<long long>(report->voxels), double(report->volume_bytes) / 1e6,
      report->rows, report->cols, report->poses, report->siddon_ms_median);
  std::printf("%8s %12s %12s %9s %9s %9s %9s %10s %9s %10s %9s\n", "P", "cells", "compression", "list MB",
              "tree MB", "build s", "DRR ms", "x Siddon", "NCC", "NCC min", "PSNR dB");
  for (const auto& r : report->rows_by_pivot)
    std::printf("%8.3f %12zu %11.2f%% %9.2f %9.2f %9.2f %9.2f %10.2f %9.6f %10.6f %9.1f\n", r.pivot, r.cells,
                r.compression_percent, double(r.list_bytes) / 1e6, double(r.render_bytes) / 1e6, r.build_s,
                r.ms_median, r.speedup_vs_siddon, r.ncc_vs_uncompressed, r.ncc_min_vs_uncompressed,
                r.psnr_db_vs_uncompressed);
  return {};
}

}  // namespace

Command add_bench_octree_command(CLI::App* parent) {
  auto* app =
      parent->add_subcommand("octree", "Octree compression of a CT: cells, memory, DRR time and fidelity");
  auto o = std::make_shared<BenchOctreeOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--pivots", o->bench.pivots, "Pivots P in [0, 1] (comma-separated)")
      ->delimiter(',')
      ->check(finite_in(0, 1));
  app->add_option("--size", o->bench.size, "DRR rows = cols, 8 to 4096")
      ->check(CLI::Range(8, 4096))
      ->capture_default_str();
  app->add_option("--poses", o->bench.poses, "Poses per view")->check(CLI::Range(1, 1000000))->capture_default_str();
  app->add_option("--repeats", o->bench.repeats, "Timed renders per pose and view")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  app->add_flag("--json", o->json, "Print the report as JSON on stdout");
  return [o]() { return run(*o); };
}

}  // namespace lftrack::cli
