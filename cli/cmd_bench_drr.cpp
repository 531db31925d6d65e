// `lftrack bench drr`: renderer speed and fidelity side by side, plastimatch as the peer.

#include <cmath>
#include <cstdio>
#include <string>

#include "cli_commands.hpp"
#include "lftrack/studies/drr_benchmark.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using studies::DrrBenchOptions;
using studies::run_drr_benchmark;
namespace {

struct BenchDrrOptions {
  SceneOptions scene;
  DrrBenchOptions bench;
  bool json = false;
  bool no_peers = false;
  bool no_light_fields = false;
};

}  // namespace

Command add_bench_drr_command(CLI::App* parent) {
  auto* app = parent->add_subcommand("drr", "Time every DRR renderer (and plastimatch) on the same poses");
  auto o = std::make_shared<BenchDrrOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--size", o->bench.size, "DRR rows = cols (the ROI window resampled), 8 to 4096")
      ->check(CLI::Range(8, 4096))
      ->capture_default_str();
  app->add_option("--poses", o->bench.poses, "Poses drawn across the envelope")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  app->add_option("--repeats", o->bench.repeats, "Timed renders per pose and view")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  app->add_option("--seed", o->bench.seed, "Pose sampling seed")->check(seed_value())->capture_default_str();
  app->add_flag("--no-peers", o->no_peers, "Skip plastimatch");
  app->add_option("--render-threads", o->bench.render_threads, "Threads for the timed renders, 1 to 256")
      ->check(CLI::Range(1, 256))
      ->capture_default_str();
  app->add_flag("--no-light-fields", o->no_light_fields, "Skip building and timing light fields");
  app->add_option("--lf-dir", o->bench.light_field_dir,
                  "Load the float light fields from this folder (`lftrack precompute`) instead of building "
                  "them; the precompute is then not timed");
  app->add_flag("--both-integrations", o->bench.both_integrations,
                "Also build the float fields the other way (slices or the exact Siddon walk) beside the "
                "scene's: both precomputes timed, both fields' DRRs against Siddon (the walk takes minutes "
                "on a real CT)");
  app->add_option("--vq-codebooks", o->bench.vq_codebooks, "VQ codebook sizes to time, each 2 to 65536 (comma-separated)")
      ->delimiter(',')
      ->check(CLI::Range(2, 65536));
  app->add_flag("--json", o->json, "Print the report as JSON on stdout");
  return [o]() -> Status {
    tracking::ThreadPool pool(o->scene.threads);
    auto prepared = load_prepared_scene(o->scene, &pool);
    if (!prepared.ok()) return prepared.status();
    DrrBenchOptions bench = o->bench;
    bench.peers = !o->no_peers;
    bench.light_fields = !o->no_light_fields;
    auto report = run_drr_benchmark(*prepared, bench, &pool);
    if (!report.ok()) return report.status();
    if (o->json) {
      std::printf("%s\n", to_json(*report).dump(2).c_str());
      return {};
    }
    std::printf("CT %s, %d x %d DRRs, %d poses x %zu views, renders on %d thread(s)\n", report->ct.c_str(),
                report->rows, report->cols, report->poses, report->views.size(), report->render_threads);
    if (report->precompute_s > 0) {
      std::printf("light fields %d x %d x %d x %d, all views precomputed in %.1f s (%s) on %d threads",
                  report->light_field_resolution[0], report->light_field_resolution[1],
                  report->light_field_resolution[2], report->light_field_resolution[3], report->precompute_s,
                  report->integration.c_str(), report->threads);
      if (report->other_precompute_s > 0)
        std::printf("; by %s in %.1f s", report->other_integration.c_str(), report->other_precompute_s);
      std::printf("\n");
    }
    std::printf("%-24s %10s %10s %13s %10s %9s %10s %8s %13s\n", "renderer", "ms median", "x Siddon",
                "NCC vs Siddon", "NCC min", "PSNR dB", "MB", "masked", "x plastimatch");
    for (const auto& r : report->renderers) {
      // Side by side where measured (light fields), else the ratio of medians; blank without a peer.
      const double x_peer = r.speedup_vs_plastimatch_side_by_side > 0 ? r.speedup_vs_plastimatch_side_by_side
                                                                      : r.speedup_vs_plastimatch;
      std::printf("%-24s %10.3f %10.1f %13.6f %10.6f %9.1f %10.1f %8.4f %13s\n", r.name.c_str(), r.ms_median,
                  r.speedup_vs_siddon, r.ncc_vs_siddon, r.ncc_min_vs_siddon, r.psnr_db_vs_siddon,
                  double(r.bytes) / 1e6, r.out_of_field_fraction,
                  x_peer > 0 ? std::to_string(static_cast<long>(std::lround(x_peer))).c_str() : "");
    }
    for (const auto& p : report->peers)
      std::printf(
          "%-24s %10.3f %10.1f %13.6f %10.6f   (%.0f ms with volume loading; max |diff| %.2e of peak)\n",
          p.name.c_str(), p.ms_median, report->renderers.front().ms_median / p.ms_median, p.ncc_vs_siddon,
          p.ncc_min_vs_siddon, p.ms_wall_median, p.max_abs_diff_rel);
    if (!report->peer_note.empty()) std::printf("peers: %s\n", report->peer_note.c_str());
    return {};
  };
}

}  // namespace lftrack::cli
