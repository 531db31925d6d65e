// `lftrack study realism`: what each part of the imaging physics costs the registration (issue 21).

#include <spdlog/spdlog.h>

#include <cstdio>
#include <filesystem>

#include "cli_commands.hpp"
#include "lftrack/session/progress_bar.hpp"
#include "lftrack/studies/realism_study.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::ProgressBar;

using studies::check_realism_shard_complete;
using studies::expected_realism_shard;
using studies::RealismFactorSummary;
using studies::RealismOptions;
using studies::RealismReport;
using studies::run_realism_study;
using studies::run_shard_task;
using studies::write_realism_outputs;
namespace {

struct RealismCliOptions {
  SceneOptions scene;
  std::string out_dir;
  bool quick = false;
  int per_bin = 0, anatomy_draws = 0, bins = 0;  // 0: the study's (or --quick's) default
  std::string renderer = "lightfield";
  std::string lf_dir;
  std::uint64_t seed = 1;
  std::string shard = "1/1";
  std::vector<std::string> only;
  bool fields_prebuilt = false;
  bool build_fields = false;
  bool check_args = false;
};

}  // namespace

void print_realism_table(const RealismReport& report) {
  std::printf("%s; image-only %s for starts <= %.0f mm%s\n", report.scene.c_str(), report.image_method.c_str(),
              report.options.image_max_mm,
              report.hybrid_method.empty() ? "" : ("; hybrid " + report.hybrid_method).c_str());
  const bool hybrid = !report.hybrid_method.empty();  // without a fiducial: no hybrid columns
  std::printf("%-20s %10s %10s %9s %9s %8s %8s", "factor set", "mean TRE", "p95 TRE", "success", "median", "fls.acc",
              "fls.rej");
  std::printf(hybrid ? " %9s %10s\n" : "\n", "hybrid", "hybrid TRE");
  for (const RealismFactorSummary& f : report.factors) {
    std::printf("%-20s %7.3f mm %7.3f mm %8.1f%% %6.0f ms %8d %8d", f.name.c_str(), f.mean_tre_mm, f.p95_tre_mm,
                100 * f.success_rate, f.median_ms, f.accepted_wrong, f.rejected_right);
    if (hybrid)
      std::printf(" %8.1f%% %7.3f mm\n", 100 * f.hybrid_success_rate, f.hybrid_mean_tre_mm);
    else
      std::printf("\n");
  }
}

namespace {

Status run(const RealismCliOptions& o) {
  auto shard = parse_shard(o.shard);
  if (!shard.ok()) return shard.status();
  if ((o.fields_prebuilt || o.build_fields) && o.lf_dir.empty())
    return invalid_argument("--fields-prebuilt and --build-fields need --lf-dir");
  RealismOptions options = o.quick ? RealismOptions::quick() : RealismOptions{};
  if (o.per_bin > 0) options.per_bin = o.per_bin;
  if (o.anatomy_draws > 0) options.anatomy_draws = o.anatomy_draws;
  if (o.bins > 0) options.bins = o.bins;
  options.renderer = o.renderer;
  options.light_field_dir = o.lf_dir;
  options.seed = o.seed;
  options.shard = shard->first;
  options.shards = shard->second;
  options.only = o.only;
  if (o.check_args) return {};
  if (!o.build_fields && o.out_dir.empty()) return invalid_argument("--out DIR is required");
  // Nothing is overwritten: a whole study needs an empty or new folder; a shard's folder is checked
  // by its task (complete: nothing to do; another study's: refused).
  std::error_code ec;
  const std::filesystem::path out(o.out_dir);
  if (!o.build_fields) {
    if (std::filesystem::exists(out / "summary.json", ec))
      return failed_precondition(o.out_dir + " holds a realism study already (summary.json); choose another --out");
    if (options.shards == 1 && std::filesystem::exists(out, ec) && !std::filesystem::is_empty(out, ec))
      return failed_precondition(o.out_dir + " is not empty; a whole realism study writes into a new or empty folder");
  }
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  auto expected = expected_realism_shard(*prepared, options);  // refuses unknown --only sets before any work
  if (!expected.ok()) return expected.status();
  auto fields_done = study_light_fields(*prepared, "realism", options.renderer, options.light_field_dir,
                                        o.build_fields, o.fields_prebuilt, &pool);
  if (!fields_done.ok()) return fields_done.status();
  if (*fields_done) return {};  // the field job
  auto run_study = [&]() -> Status {
    ProgressBar bar("realism");
    auto report = run_realism_study(*prepared, options, &pool, [&](double f) { bar.update(f); });
    if (!report.ok()) return report.status();
    bar.finish();
    LFTRACK_RETURN_IF_ERROR(write_realism_outputs(*report, o.out_dir));
    if (options.shards > 1) {
      std::printf("shard %d/%d of every factor set written under %s/<set>/; join the shards with `lftrack study "
                  "merge --out DIR SHARD_DIR...`\n",
                  options.shard, options.shards, o.out_dir.c_str());
      return {};
    }
    print_realism_table(*report);
    std::printf("wrote %s/{summary.json,realism.csv,realism_tre.png,realism_rates.png} and a capture-range study per factor set\n",
                o.out_dir.c_str());
    return {};
  };
  if (options.shards == 1) return run_study();
  std::string said;
  const Status s = run_shard_task(
      o.out_dir, [&] { return check_realism_shard_complete(o.out_dir, *expected); }, run_study, &said);
  if (s.ok() && !said.empty()) std::printf("%s\n", said.c_str());
  return s;
}

}  // namespace

Command add_study_realism_command(CLI::App* parent) {
  auto* app = parent->add_subcommand(
      "realism", "TRE and success per imaging-physics factor: ideal, each part alone, clinical (issue 21)");
  auto o = std::make_shared<RealismCliOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--out", o->out_dir, "Output folder");
  app->add_flag("--quick", o->quick, "4 gold poses and 2 anatomy draws per factor set (minutes)");
  app->add_option("--gold-poses", o->per_bin, "Gold poses per factor set, each with one start per 2 mm bin")
      ->check(CLI::Range(1, 10000));
  app->add_option("--anatomy-draws", o->anatomy_draws, "Deformed patients the gold poses share")
      ->check(CLI::Range(1, 1000));
  app->add_option("--bins", o->bins, "Start bins of 2 mm of initial TRE (default 8: starts to 16 mm)")
      ->check(CLI::Range(1, 8));
  app->add_option("--renderer", o->renderer, "DRR renderer inside the registration")->capture_default_str();
  app->add_option("--lf-dir", o->lf_dir, "Light-field folder (default: out/lightfields/<scene>)");
  app->add_option("--seed", o->seed, "Seed of gold poses, starts, noise and anatomy")->check(seed_value())->capture_default_str();
  app->add_option("--shard", o->shard, "Run only shard k of n (k/n) of the gold poses")->capture_default_str();
  app->add_option("--only", o->only, "Factor sets to run (ideal, spectrum, scatter, detector, soft_tissue, "
                                     "adjacent_vertebrae, breathing, clinical)")
      ->delimiter(',');
  app->add_flag("--fields-prebuilt", o->fields_prebuilt,
                "With --lf-dir: refuse to build missing light fields (a job array's tasks)");
  app->add_flag("--build-fields", o->build_fields,
                "Build the light fields into --lf-dir if they are not there, and exit (a job array's first job)");
  app->add_flag("--check-args", o->check_args, "Check the options and exit (`study submit` does, before submitting)");
  return [o] { return run(*o); };
}

}  // namespace lftrack::cli
