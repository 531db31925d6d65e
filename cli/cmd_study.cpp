// `lftrack study capture-range`: the capture-range study of the papers on a scene.

#include <spdlog/spdlog.h>

#include <cstdio>
#include <filesystem>
#include <system_error>

#include <unistd.h>

#include "cli_commands.hpp"
#include "lftrack/session/progress_bar.hpp"
#include "lftrack/studies/capture_range_study.hpp"
#include "lftrack/studies/geometry_sensitivity.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::ProgressBar;

using studies::CaptureRangeOptions;
using studies::CaptureRangeReport;
using studies::check_capture_range_shard_complete;
using studies::parse_registration_method;
using studies::run_capture_range_study;
using studies::run_geometry_sensitivity;
using studies::run_shard_task;
using studies::SensitivityCase;
using studies::SensitivityOptions;
using studies::study_scene_fingerprint;
using studies::write_capture_range_outputs;
using studies::write_capture_range_shard;
using studies::write_sensitivity_outputs;
namespace {

struct CaptureRangeCliOptions {
  SceneOptions scene;
  std::string out_dir;
  int per_bin = 30;
  int bins = 8;
  std::vector<std::string> methods{"papers:mi", "cmaes:mi", "papers:mi+fiducial"};
  std::string renderer = "lightfield";
  std::string lf_dir;
  std::uint64_t seed = 1;
  std::string shard = "1/1";
  bool fields_prebuilt = false;
  bool build_fields = false;
  bool check_args = false;
  std::string physics = "ideal";
  int anatomy_draws = 5;
};

void print_capture_range(const CaptureRangeReport& report) {
  std::printf("%-24s %8s %8s %9s %9s %9s %9s %9s\n", "method", "success", "<2.5mm", "mean TRE", "max TRE",
              "capture", "median", "p95");
  for (const auto& s : report.summaries)
    std::printf("%-24s %7.1f%% %7.1f%% %6.3f mm %6.3f mm %6.1f mm %6.0f ms %6.0f ms\n", s.name.c_str(),
                100 * s.success_rate, 100 * s.success_rate_loose, s.mean_tre_mm, s.max_tre_mm,
                s.capture_range_mm, s.median_ms, s.p95_ms);
  // What the loop would do with each result: the verdict against the truth (right: TRE < 2 mm).
  std::printf("%-24s %9s %9s %9s %9s   (the registration verdict; right: TRE < %.1f mm)\n", "method", "acc.right",
              "FALSE ACC", "false rej", "rej.wrong", report.options.success_mm);
  for (const auto& s : report.summaries)
    std::printf("%-24s %9d %9d %9d %9d\n", s.name.c_str(), s.accepted_right, s.accepted_wrong, s.rejected_right,
                s.rejected_wrong);
}

Status run(const CaptureRangeCliOptions& o) {
  auto shard = parse_shard(o.shard);
  if (!shard.ok()) return shard.status();
  if ((o.fields_prebuilt || o.build_fields) && o.lf_dir.empty())
    return invalid_argument("--fields-prebuilt and --build-fields need --lf-dir");
  CaptureRangeOptions options;
  for (const auto& text : o.methods) {
    auto m = parse_registration_method(text);
    if (!m.ok()) return m.status();
    options.methods.push_back(*m);
  }
  options.per_bin = o.per_bin;
  options.bins = o.bins;
  options.seed = o.seed;
  options.renderer = o.renderer;
  options.light_field_dir = o.lf_dir;
  options.shard = shard->first;
  options.shards = shard->second;
  if (auto checked = study_physics(o.physics, nullptr); !checked.ok()) return checked.status();
  options.anatomy_draws = o.anatomy_draws;
  if (o.check_args) return {};
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  const StudyPhysics physics = *study_physics(o.physics, &*prepared);
  options.physics = physics.physics;
  options.physics_name = physics.name;
  if (!o.build_fields && o.out_dir.empty()) return invalid_argument("--out DIR is required");
  auto fields_done = study_light_fields(*prepared, "capture-range", options.renderer, options.light_field_dir,
                                        o.build_fields, o.fields_prebuilt, &pool);
  if (!fields_done.ok()) return fields_done.status();
  if (*fields_done) return {};  // the field job
  CaptureRangeReport expected;
  expected.scene = prepared->scene.name;
  expected.fingerprint = study_scene_fingerprint(*prepared);
  expected.options = options;
  std::string said;
  const Status s = run_shard_task(
      o.out_dir, [&] { return check_capture_range_shard_complete(o.out_dir, expected); },
      [&]() -> Status {
        ProgressBar bar("capture range");
        auto report = run_capture_range_study(*prepared, options, &pool, [&](double f) { bar.update(f); });
        if (!report.ok()) return report.status();
        bar.finish();
        if (options.shards > 1) {
          LFTRACK_RETURN_IF_ERROR(write_capture_range_shard(*report, o.out_dir));
          std::printf("shard %d/%d: %zu runs; wrote %s/{runs.csv,study.json}; join the shards with "
                      "`lftrack study merge --out DIR SHARD_DIR...`\n",
                      options.shard, options.shards, report->runs.size(), o.out_dir.c_str());
          return {};
        }
        LFTRACK_RETURN_IF_ERROR(write_capture_range_outputs(*report, o.out_dir));
        print_capture_range(*report);
        std::printf("wrote %s/{runs.csv,summary.json,capture_range.png,verdict.png}\n", o.out_dir.c_str());
        return {};
      },
      &said);
  if (s.ok() && !said.empty()) std::printf("%s\n", said.c_str());
  return s;
}

}  // namespace

Command add_study_capture_range_command(CLI::App* parent) {
  auto* app = parent->add_subcommand("capture-range", "Success rate against initial TRE, per method");
  auto o = std::make_shared<CaptureRangeCliOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--out", o->out_dir, "Output folder");
  app->add_option("--per-bin", o->per_bin, "Starts per bin")
      ->check(CLI::Range(1, 10000))
      ->capture_default_str();
  app->add_option("--bins", o->bins, "Bins of 2 mm initial TRE")
      ->check(CLI::Range(1, 32))
      ->capture_default_str();
  app->add_option("--methods", o->methods, "Methods PLAN:MEASURE[+fiducial]")
      ->delimiter(',')
      ->capture_default_str();
  app->add_option("--renderer", o->renderer, "DRR renderer inside the registration")->capture_default_str();
  app->add_option("--lf-dir", o->lf_dir, "Light-field folder (default: out/lightfields/<scene>)");
  app->add_option("--seed", o->seed, "Seed of gold poses, starts and noise")->check(seed_value())->capture_default_str();
  app->add_option("--shard", o->shard, "Run only shard k of n (k/n) of the samples, for a job array; join with "
                                       "`study merge`")
      ->capture_default_str();
  app->add_flag("--fields-prebuilt", o->fields_prebuilt,
                "With --lf-dir: refuse to build missing light fields (a job array's tasks)");
  app->add_flag("--build-fields", o->build_fields,
                "Build the light fields into --lf-dir if they are not there, and exit (a job array's first job)");
  app->add_flag("--check-args", o->check_args, "Check the options and exit (`study submit` does, before submitting)");
  app->add_option("--physics", o->physics,
                  "What the frames carry: ideal (DRRs of the planning CT), clinical, or scene (its sim.physics)")
      ->capture_default_str();
  app->add_option("--anatomy-draws", o->anatomy_draws, "Deformed patients the gold poses share (with anatomy)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  return [o] { return run(*o); };
}

namespace {

struct SensitivityCliOptions {
  SceneOptions scene;
  SensitivityOptions study;
  bool json = false;
  std::string out_dir;
};

}  // namespace

Command add_study_sensitivity_command(CLI::App* parent) {
  auto* app =
      parent->add_subcommand("sensitivity", "TRE added by calibration errors (source, detector, pitch)");
  auto o = std::make_shared<SensitivityCliOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--runs", o->study.runs, "Registrations per case")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  app->add_option("--plan", o->study.plan, "Registration plan")->capture_default_str();
  app->add_option("--start-tre", o->study.start_tre_mm, "Initial mean TRE of the starts (mm, more than 0, at most 100)")
      ->check(finite_in(0, 100, true))
      ->capture_default_str();
  app->add_option("--seed", o->study.seed, "Seed of gold poses, starts and noise")->check(seed_value())->capture_default_str();
  app->add_flag("--json", o->json, "Print the report as JSON on stdout");
  app->add_option("--out", o->out_dir,
                  "Also write runs.csv, summary.json and verdict.png (the registration verdict per case) into this "
                  "folder, new or empty (nothing in it is replaced)")
      ->check(not_empty());
  return [o]() -> Status {
    // The folder before the work: minutes of registrations are not lost to a folder that cannot
    // be written, and nothing an earlier study wrote is replaced.
    if (!o->out_dir.empty()) {
      std::error_code ec;
      const std::filesystem::path out(o->out_dir);
      if (std::filesystem::exists(std::filesystem::symlink_status(out, ec)) && !std::filesystem::is_directory(out, ec))
        return failed_precondition(o->out_dir + ": not a folder");
      if (std::filesystem::exists(out, ec) && !std::filesystem::is_empty(out, ec))
        return failed_precondition(o->out_dir + " is not empty; a sensitivity study writes into a new or empty folder");
      std::filesystem::create_directories(out, ec);
      if (ec || ::access(out.c_str(), W_OK) != 0)
        return io_error(o->out_dir + ": cannot create or write the folder" + (ec ? ": " + ec.message() : ""));
    }
    tracking::ThreadPool pool(o->scene.threads);
    auto prepared = load_prepared_scene(o->scene, &pool);
    if (!prepared.ok()) return prepared.status();
    auto report = run_geometry_sensitivity(*prepared, o->study, &pool);
    if (!report.ok()) return report.status();
    // The report is printed before the files are written: a write that fails loses no figure.
    const Status written = o->out_dir.empty() ? Status{} : write_sensitivity_outputs(*report, o->out_dir);
    if (o->json) {
      std::printf("%s\n", to_json(*report).dump(2).c_str());
      return written;
    }
    std::printf("%-76s %10s %10s %12s\n", "model geometry", "TRE mm", "max mm", "added mm");
    for (const SensitivityCase& c : report->cases)
      std::printf("%-76s %10.3f %10.3f %12.3f\n", c.name.c_str(), c.mean_tre_mm, c.max_tre_mm,
                  c.mean_added_mm);
    // What the loop would do with each result: the verdict against the truth.
    std::printf("%-18s %9s %9s %9s %9s   (the registration verdict, %s; right: TRE < %.2f mm)\n", "case",
                "acc.right", "FALSE ACC", "false rej", "rej.wrong", report->measure.c_str(),
                report->verdict_tolerance_mm);
    for (const SensitivityCase& c : report->cases)
      std::printf("%-18s %9d %9d %9d %9d\n", c.key.c_str(), c.verdict.accepted_right, c.verdict.accepted_wrong,
                  c.verdict.rejected_right, c.verdict.rejected_wrong);
    if (!o->out_dir.empty() && written.ok())
      std::printf("wrote %s/{runs.csv,summary.json,verdict.png}\n", o->out_dir.c_str());
    return written;
  };
}

}  // namespace lftrack::cli
