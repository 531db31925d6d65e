// `lftrack study trade` and `lftrack study merge`: the speed-accuracy trade study, sharded.

#include <spdlog/spdlog.h>

#include <cstdio>

#include "cli_commands.hpp"
#include "lftrack/studies/trade_study.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "lftrack/host/progress_bar.hpp"

namespace lftrack::host::cli {
namespace {

struct TradeCliOptions {
  SceneOptions scene;
  std::string out_dir;
  bool quick = false;
  int problems = 0;
  std::string shard = "1/1";
  std::uint64_t seed = 1;
  bool list = false;
  std::vector<std::string> points;
};

Result<std::pair<int, int>> parse_shard(const std::string& text) {
  int k = 0, n = 0;
  char tail = 0;
  if (std::sscanf(text.c_str(), "%d/%d%c", &k, &n, &tail) != 2 || n < 1 || k < 1 || k > n)
    return invalid_argument("--shard '" + text + "': expected k/n with 1 <= k <= n, e.g. 3/8");
  return std::make_pair(k, n);
}

void print_front(const TradeStudy& study) {
  std::printf("%-22s %10s %10s %10s %10s %8s %10s\n", "Pareto front", "median ms", "p95 ms", "mean TRE",
              "p95 TRE", "success", "memory MB");
  for (const auto& r : pareto_front(study.results))
    std::printf("%-22s %10.1f %10.1f %10.3f %10.3f %7.0f%% %10.2f\n", r.point.id.c_str(), r.median_ms,
                r.p95_ms, r.mean_tre_mm, r.p95_tre_mm, 100 * r.success_rate, r.memory_bytes / 1e6);
}

Status run_trade(const TradeCliOptions& o) {
  auto shard = parse_shard(o.shard);
  if (!shard.ok()) return shard.status();
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  if (o.list) {
    for (const auto& t : trade_points(*prepared, o.quick)) std::printf("%s\n", t.id.c_str());
    return {};
  }
  if (o.out_dir.empty()) return invalid_argument("--out DIR is required");
  TradeOptions options;
  options.quick = o.quick;
  options.problems = o.problems;
  options.shard = shard->first;
  options.shards = shard->second;
  options.seed = o.seed;
  options.only = o.points;
  ProgressBar bar("trade study");
  std::string last_point;
  auto study = run_trade_study(*prepared, options, &pool, [&](double f, const std::string& point) {
    if (point != last_point) spdlog::debug("point {}", point);
    last_point = point;
    bar.update(f);
  });
  if (!study.ok()) return study.status();
  bar.finish();
  if (options.shards > 1) {
    LFTRACK_RETURN_IF_ERROR(write_trade_shard(*study, o.out_dir));
    std::printf(
        "shard %d/%d: %zu of %d points; wrote %s/{points.csv,study.json}; join the shards with "
        "`lftrack study merge --out DIR SHARD_DIR...`\n",
        options.shard, options.shards, study->results.size(), study->points_total, o.out_dir.c_str());
    return {};
  }
  LFTRACK_RETURN_IF_ERROR(write_trade_outputs(*study, o.out_dir));
  print_front(*study);
  std::printf("wrote %s/{points.csv,summary.md,tre_vs_time.png,memory_vs_fidelity.png}\n", o.out_dir.c_str());
  return {};
}

struct MergeCliOptions {
  std::string out_dir;
  std::vector<std::string> shards;
};

Status run_merge(const MergeCliOptions& o) {
  std::vector<TradeStudy> shards;
  for (const auto& dir : o.shards) {
    auto s = read_trade_shard(dir);
    if (!s.ok()) return s.status();
    shards.push_back(std::move(s).value());
  }
  auto merged = merge_trade_shards(shards);
  if (!merged.ok()) return merged.status();
  LFTRACK_RETURN_IF_ERROR(write_trade_outputs(*merged, o.out_dir));
  print_front(*merged);
  std::printf(
      "merged %zu shards, %zu points; wrote "
      "%s/{points.csv,summary.md,tre_vs_time.png,memory_vs_fidelity.png}\n",
      shards.size(), merged->results.size(), o.out_dir.c_str());
  return {};
}

}  // namespace

Command add_study_trade_command(CLI::App* parent) {
  auto* app = parent->add_subcommand(
      "trade",
      "Speed against accuracy: every knob's operating point, a CSV, plots with the Pareto front, a summary");
  auto o = std::make_shared<TradeCliOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--out", o->out_dir, "Output folder");
  app->add_flag("--quick", o->quick, "Fewer points and problems and a coarser baseline field (minutes)");
  app->add_option("--problems", o->problems, "Registration problems per point (default 6 quick, 24 full)")
      ->check(CLI::Range(1, 10000));
  app->add_option("--shard", o->shard,
                  "Run only shard k of n (k/n), for a job array; join with `study merge`")
      ->capture_default_str();
  app->add_option("--seed", o->seed, "Seed of the problems")->capture_default_str();
  app->add_flag("--list", o->list, "Print the points' ids and exit");
  app->add_option("--points", o->points, "Run only these points (ids from --list, comma-separated)")
      ->delimiter(',');
  return [o]() { return run_trade(*o); };
}

Command add_study_merge_command(CLI::App* parent) {
  auto* app =
      parent->add_subcommand("merge", "Join the shards of a trade study and write its plots and summary");
  auto o = std::make_shared<MergeCliOptions>();
  app->add_option("--out", o->out_dir, "Output folder")->required();
  app->add_option("shards", o->shards, "The shards' output folders")
      ->required()
      ->check(CLI::ExistingDirectory);
  return [o]() { return run_merge(*o); };
}

}  // namespace lftrack::host::cli
