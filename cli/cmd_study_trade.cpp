// `lftrack study trade`: the speed-accuracy trade study, sharded (joined by `study merge`,
// cmd_study_merge.cpp).

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "cli_commands.hpp"
#include "lftrack/session/progress_bar.hpp"
#include "lftrack/studies/capture_range_study.hpp"
#include "lftrack/studies/slurm_job_array.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "lftrack/studies/trade_study.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::PreparedScene;
using session::ProgressBar;

using studies::build_trade_fields;
using studies::check_trade_shard_complete;
using studies::pareto_front;
using studies::run_shard_task;
using studies::run_trade_study;
using studies::study_scene_fingerprint;
using studies::trade_points;
using studies::trade_problem_count;
using studies::trade_shard_points;
using studies::TradeOptions;
using studies::TradePoint;
using studies::TradeResult;
using studies::TradeStudy;
using studies::write_trade_outputs;
using studies::write_trade_shard;
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
  std::string lf_dir;
  bool fields_prebuilt = false;
  bool build_fields = false;
  bool check_args = false;
  std::string physics = "ideal";
};

}  // namespace

void print_trade_front(const TradeStudy& study) {
  std::printf("%-22s %10s %10s %10s %10s %8s %10s\n", "Pareto front", "median ms", "p95 ms", "mean TRE",
              "p95 TRE", "success", "memory MB");
  for (const auto& r : pareto_front(study.results))
    std::printf("%-22s %10.1f %10.1f %10.3f %10.3f %7.0f%% %10.2f\n", r.point.id.c_str(), r.median_ms,
                r.p95_ms, r.mean_tre_mm, r.p95_tre_mm, 100 * r.success_rate, r.memory_bytes / 1e6);
  for (const auto& r : study.results)
    if (r.failed())
      std::printf("FAILED %-15s %d of %d registrations failed: %s\n", r.point.id.c_str(), r.failed_runs, r.runs,
                  r.failure.empty() ? "(reason not recorded)" : r.failure.c_str());
  // What the loop would do with each point's results: the verdict against the truth.
  if (std::none_of(study.results.begin(), study.results.end(), [](const TradeResult& r) { return r.judged(); }))
    return;
  char right[64];
  if (study.verdict_tolerance_mm > 0)
    std::snprintf(right, sizeof right, "TRE < %.2f mm", study.verdict_tolerance_mm);
  else
    std::snprintf(right, sizeof right, "TRE under each scene's tolerance");
  std::printf("%-22s %9s %9s %9s %9s   (right: %s)\n", "Registration verdict", "acc.right", "FALSE ACC",
              "false rej", "rej.wrong", right);
  for (const auto& r : study.results)  // indented: a point named here is not on the front above
    if (r.judged())
      std::printf("  %-20s %9d %9d %9d %9d\n", r.point.id.c_str(), r.verdict.accepted_right,
                  r.verdict.accepted_wrong, r.verdict.rejected_right, r.verdict.rejected_wrong);
}

namespace {

Status run_trade_points(const PreparedScene& prepared, const TradeOptions& options, tracking::ThreadPool* pool,
                        const std::string& out_dir);

Status run_trade(const TradeCliOptions& o) {
  auto shard = parse_shard(o.shard);
  if (!shard.ok()) return shard.status();
  if (o.fields_prebuilt && o.lf_dir.empty()) return invalid_argument("--fields-prebuilt needs --lf-dir");
  if (auto checked = study_physics(o.physics, nullptr); !checked.ok()) return checked.status();
  if (o.check_args) return {};
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  if (o.list) {
    for (const auto& t : trade_points(*prepared, o.quick)) std::printf("%s\n", t.id.c_str());
    return {};
  }
  TradeOptions options;
  options.quick = o.quick;
  options.problems = o.problems;
  options.shard = shard->first;
  options.shards = shard->second;
  options.seed = o.seed;
  options.only = o.points;
  options.field_dir = o.lf_dir;
  options.fields_prebuilt = o.fields_prebuilt;
  const StudyPhysics physics = *study_physics(o.physics, &*prepared);
  options.physics = physics.physics;
  options.physics_name = physics.name;
  if (o.build_fields) {
    if (o.lf_dir.empty()) return invalid_argument("--build-fields needs --lf-dir DIR");
    return build_trade_fields(*prepared, options, &pool, [](const std::string& line) {
      std::printf("%s\n", line.c_str());
      std::fflush(stdout);
    });
  }
  if (o.out_dir.empty()) return invalid_argument("--out DIR is required");
  // What this shard's complete result holds, for a task that finds one already there.
  int points_total = 0;
  auto mine = trade_shard_points(*prepared, options, &points_total);
  if (!mine.ok()) return mine.status();
  TradeStudy expected;
  expected.scene = prepared->scene.name;
  expected.fingerprint = study_scene_fingerprint(*prepared);
  expected.seed = options.seed;
  expected.problems = trade_problem_count(options);
  expected.quick = options.quick;
  expected.shard = options.shard;
  expected.shards = options.shards;
  expected.points_total = points_total;
  expected.physics = options.physics_name;
  expected.physics_description = sim_spec::describe(options.physics);
  expected.verdict_tolerance_mm = prepared->scene.safety.beam_tolerance_mm;
  std::vector<std::string> ids;
  for (const TradePoint& t : *mine) ids.push_back(t.id);
  std::string said;
  const Status s = run_shard_task(
      o.out_dir, [&] { return check_trade_shard_complete(o.out_dir, expected, ids); },
      [&] { return run_trade_points(*prepared, options, &pool, o.out_dir); }, &said);
  if (s.ok() && !said.empty()) std::printf("%s\n", said.c_str());
  return s;
}

Status run_trade_points(const PreparedScene& prepared, const TradeOptions& options, tracking::ThreadPool* pool,
                        const std::string& out_dir) {
  ProgressBar bar("trade study");
  std::string last_point;
  auto study = run_trade_study(prepared, options, pool, [&](double f, const std::string& point) {
    if (point != last_point) spdlog::debug("point {}", point);
    last_point = point;
    bar.update(f);
  });
  if (!study.ok()) return study.status();
  bar.finish();
  if (options.shards > 1) {
    LFTRACK_RETURN_IF_ERROR(write_trade_shard(*study, out_dir));
    std::printf(
        "shard %d/%d: %zu of %d points; wrote %s/{points.csv,study.json}; join the shards with "
        "`lftrack study merge --out DIR SHARD_DIR...`\n",
        options.shard, options.shards, study->results.size(), study->points_total, out_dir.c_str());
    return {};
  }
  LFTRACK_RETURN_IF_ERROR(write_trade_outputs(*study, out_dir));
  print_trade_front(*study);
  std::printf("wrote %s/{points.csv,runs.csv,summary.md,summary.json,tre_vs_time.png,memory_vs_fidelity.png,"
              "verdict.png}\n",
              out_dir.c_str());
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
  app->add_option("--physics", o->physics,
                  "What the frames carry: ideal (DRRs of the planning CT), clinical, or scene (its sim.physics)");
  app->add_option("--problems", o->problems, "Registration problems per point (default 6 quick, 24 full)")
      ->check(CLI::Range(1, 10000));
  app->add_option("--shard", o->shard,
                  "Run only shard k of n (k/n), for a job array; join with `study merge`")
      ->capture_default_str();
  app->add_option("--seed", o->seed, "Seed of the problems")->check(seed_value())->capture_default_str();
  app->add_flag("--list", o->list, "Print the points' ids and exit");
  app->add_option("--points", o->points, "Run only these points (ids from --list, comma-separated)")
      ->delimiter(',');
  app->add_option("--lf-dir", o->lf_dir,
                  "Keep the float light fields in this folder: load them if built, else build and save them");
  app->add_flag("--fields-prebuilt", o->fields_prebuilt,
                "With --lf-dir: refuse to build a missing field (a job array's tasks)");
  app->add_flag("--build-fields", o->build_fields,
                "Build every field set the study needs into --lf-dir and exit (a job array's first job)");
  app->add_flag("--check-args", o->check_args, "Check the options and exit (`study submit` does, before submitting)");
  return [o]() { return run_trade(*o); };
}

}  // namespace lftrack::cli
