// `lftrack study trade` and `lftrack study merge`: the speed-accuracy trade study, sharded, and the
// merge of any sharded study's shards (trade, capture range), per scene and pooled.

#include <spdlog/spdlog.h>

#include <cstdio>
#include <fstream>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "cli_commands.hpp"
#include "lftrack/studies/capture_range_study.hpp"
#include "lftrack/studies/slurm_job_array.hpp"
#include "lftrack/studies/study_shard.hpp"
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
  std::string lf_dir;
  bool fields_prebuilt = false;
  bool build_fields = false;
  bool check_args = false;
  std::string physics = "ideal";
};

void print_front(const TradeStudy& study) {
  std::printf("%-22s %10s %10s %10s %10s %8s %10s\n", "Pareto front", "median ms", "p95 ms", "mean TRE",
              "p95 TRE", "success", "memory MB");
  for (const auto& r : pareto_front(study.results))
    std::printf("%-22s %10.1f %10.1f %10.3f %10.3f %7.0f%% %10.2f\n", r.point.id.c_str(), r.median_ms,
                r.p95_ms, r.mean_tre_mm, r.p95_tre_mm, 100 * r.success_rate, r.memory_bytes / 1e6);
}

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
  expected.physics_description = sim::describe(options.physics);
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
  print_front(*study);
  std::printf("wrote %s/{points.csv,summary.md,tre_vs_time.png,memory_vs_fidelity.png}\n", out_dir.c_str());
  return {};
}

struct MergeCliOptions {
  std::string out_dir;
  std::vector<std::string> shards;
};

// Which study a shard folder holds ("trade" for folders written before study.json named it).
Result<std::string> study_kind(const std::string& dir) {
  std::ifstream in(std::filesystem::path(dir) / "study.json");
  if (!in) return not_found(dir + "/study.json: no such file (not a study's shard?)");
  try {
    return nlohmann::json::parse(in).value("study", std::string("trade"));
  } catch (const std::exception& e) {
    return corrupt_data(dir + "/study.json: " + e.what());
  }
}

template <typename Study>
using Merger = std::function<Result<Study>(const std::vector<Study>&)>;

// Shards grouped by scene (in the order first seen), each group merged; `name_of` names a study's scene.
template <typename Study>
Result<std::vector<Study>> merge_per_scene(const std::vector<Study>& shards, const Merger<Study>& merge,
                                           const std::function<std::string(const Study&)>& name_of) {
  std::vector<std::string> order;
  std::map<std::string, std::vector<Study>> groups;
  for (const Study& s : shards) {
    if (!groups.count(name_of(s))) order.push_back(name_of(s));
    groups[name_of(s)].push_back(s);
  }
  std::vector<Study> merged;
  for (const std::string& name : order) {
    auto m = merge(groups[name]);
    if (!m.ok()) return m.status().with_context("scene '" + name + "'");
    merged.push_back(std::move(m).value());
  }
  return merged;
}

// Several scenes' folders under the merge's --out: one each, none called "pooled".
template <typename Study>
Status check_scene_folders(const std::vector<Study>& merged) {
  std::set<std::string> folders{"pooled"};
  for (const Study& s : merged)
    if (!folders.insert(folder_safe_name(s.scene)).second)
      return failed_precondition("merge: scene '" + s.scene + "' would be written to the folder '" +
                                 folder_safe_name(s.scene) + "', which another scene or the pooled study takes; "
                                 "rename the scene");
  return {};
}

Status merge_trade(const std::vector<std::string>& dirs, const std::filesystem::path& out) {
  std::vector<TradeStudy> shards;
  for (const auto& dir : dirs) {
    auto s = read_trade_shard(dir);
    if (!s.ok()) return s.status();
    shards.push_back(std::move(s).value());
  }
  auto merged = merge_per_scene<TradeStudy>(shards, merge_trade_shards, [](const TradeStudy& s) { return s.scene; });
  if (!merged.ok()) return merged.status();
  if (merged->size() == 1) {
    LFTRACK_RETURN_IF_ERROR(write_trade_outputs(merged->front(), out));
    print_front(merged->front());
    std::printf("merged %zu shards, %zu points; wrote %s/{points.csv,summary.md,tre_vs_time.png,"
                "memory_vs_fidelity.png}\n",
                shards.size(), merged->front().results.size(), out.c_str());
    return {};
  }
  LFTRACK_RETURN_IF_ERROR(check_scene_folders(*merged));
  for (const TradeStudy& s : *merged) LFTRACK_RETURN_IF_ERROR(write_trade_outputs(s, out / folder_safe_name(s.scene)));
  std::vector<std::string> left_out;
  auto pooled = pool_trade_studies(*merged, &left_out);
  if (!pooled.ok()) return pooled.status();
  LFTRACK_RETURN_IF_ERROR(write_trade_outputs(*pooled, out / "pooled"));
  std::printf("Pooled over %zu scenes (%d problems per point):\n", merged->size(), pooled->problems);
  print_front(*pooled);
  if (!left_out.empty()) {
    std::string ids;
    for (const auto& id : left_out) ids += (ids.empty() ? "" : ", ") + id;
    std::printf("left out of the pooled study (not in every scene): %s\n", ids.c_str());
  }
  std::printf("merged %zu shards of %zu scenes; wrote %s/<scene>/ per scene and %s/pooled/\n", shards.size(),
              merged->size(), out.c_str(), out.c_str());
  return {};
}

Status merge_capture_range(const std::vector<std::string>& dirs, const std::filesystem::path& out) {
  std::vector<CaptureRangeReport> shards;
  for (const auto& dir : dirs) {
    auto s = read_capture_range_shard(dir);
    if (!s.ok()) return s.status();
    shards.push_back(std::move(s).value());
  }
  auto merged = merge_per_scene<CaptureRangeReport>(shards, merge_capture_range_shards,
                                                    [](const CaptureRangeReport& s) { return s.scene; });
  if (!merged.ok()) return merged.status();
  if (merged->size() == 1) {
    LFTRACK_RETURN_IF_ERROR(write_capture_range_outputs(merged->front(), out));
    std::printf("merged %zu shards, %zu runs; wrote %s/{runs.csv,summary.json,capture_range.png}\n", shards.size(),
                merged->front().runs.size(), out.c_str());
    return {};
  }
  LFTRACK_RETURN_IF_ERROR(check_scene_folders(*merged));
  for (const CaptureRangeReport& s : *merged)
    LFTRACK_RETURN_IF_ERROR(write_capture_range_outputs(s, out / folder_safe_name(s.scene)));
  auto pooled = pool_capture_range_reports(*merged);
  if (!pooled.ok()) return pooled.status();
  LFTRACK_RETURN_IF_ERROR(write_capture_range_outputs(*pooled, out / "pooled"));
  std::printf("merged %zu shards of %zu scenes; wrote %s/<scene>/ per scene and %s/pooled/\n", shards.size(),
              merged->size(), out.c_str(), out.c_str());
  return {};
}

Status run_merge(const MergeCliOptions& o) {
  // The output is never one of the shards (a merge there would overwrite that shard's result).
  std::error_code ec;
  const auto out = std::filesystem::weakly_canonical(o.out_dir, ec);
  for (const auto& dir : o.shards) {
    const auto shard = std::filesystem::weakly_canonical(dir, ec);
    const auto rel = out.lexically_relative(shard);
    if (out == shard || (!rel.empty() && *rel.begin() != ".."))
      return invalid_argument("merge: --out " + o.out_dir + " is, or is inside, the shard folder " + dir +
                              "; choose a folder of its own");
  }
  std::string kind;
  for (const auto& dir : o.shards) {
    auto k = study_kind(dir);
    if (!k.ok()) return k.status();
    if (!kind.empty() && *k != kind)
      return failed_precondition("merge: " + dir + " holds a " + *k + " study, the others a " + kind + " study");
    kind = *k;
  }
  if (kind == "trade") return merge_trade(o.shards, o.out_dir);
  if (kind == "capture-range") return merge_capture_range(o.shards, o.out_dir);
  return unsupported("merge: unknown study '" + kind + "'");
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
  app->add_option("--seed", o->seed, "Seed of the problems")->capture_default_str();
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

Command add_study_merge_command(CLI::App* parent) {
  auto* app =
      parent->add_subcommand("merge", "Join the shards of a trade or capture-range study (several scenes: per scene "
                                      "and pooled) and write its plots and summary");
  auto o = std::make_shared<MergeCliOptions>();
  app->add_option("--out", o->out_dir, "Output folder")->required();
  app->add_option("shards", o->shards, "The shards' output folders")
      ->required()
      ->check(CLI::ExistingDirectory);
  return [o]() { return run_merge(*o); };
}

}  // namespace lftrack::host::cli
