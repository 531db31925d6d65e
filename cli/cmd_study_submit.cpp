// `lftrack study submit` and `lftrack study status`: a sharded study as a Slurm job array, and
// where its shards stand (issue 25).

#include <nlohmann/json.hpp>
#include <unistd.h>

#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "cli_commands.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/capture_range_study.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"  // run_process
#include "lftrack/studies/realism_study.hpp"
#include "lftrack/studies/slurm_job_array.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "lftrack/studies/trade_study.hpp"

namespace lftrack::cli {

using session::load_scene;
using session::printable;

using studies::check_job_array_spec;
using studies::folder_safe_name;
using studies::job_array_scripts;
using studies::JobArraySpec;
using studies::JobScript;
using studies::read_capture_range_shard;
using studies::read_realism_shard;
using studies::read_shard_task;
using studies::read_trade_shard;
using studies::run_process;
using studies::shard_dir;
using studies::ShardPhase;
using studies::ShardTask;
using studies::shell_quote;
using studies::submit_job_array;
namespace {

namespace fs = std::filesystem;

struct SubmitCliOptions {
  std::string scheduler;
  std::string study;
  std::vector<std::string> scenes;
  std::string out_dir;
  int shards = 0;
  std::string partition, time_limit;
  int cpus_per_task = 2;
  bool dry_run = false;
  std::vector<std::string> study_args;
};

Result<std::string> this_program() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (ec) return io_error("cannot find this program's path (/proc/self/exe): " + ec.message());
  return self.string();
}

Status run_submit(const SubmitCliOptions& o) {
  if (o.scheduler != "slurm") return invalid_argument("--scheduler '" + o.scheduler + "': only slurm is supported");
  JobArraySpec spec;
  spec.study = o.study;
  std::error_code ec;
  for (const std::string& file : o.scenes) {
    auto scene = load_scene(file);  // a scene that does not load is refused before anything is written
    if (!scene.ok()) return scene.status();
    spec.scenes.push_back(file.rfind("builtin:", 0) == 0 ? file : fs::absolute(file, ec).lexically_normal().string());
    spec.scene_names.push_back(folder_safe_name(scene->name));
  }
  spec.out_dir = fs::absolute(o.out_dir, ec).lexically_normal();
  spec.work_dir = fs::current_path(ec);
  auto program = this_program();
  if (!program.ok()) return program.status();
  spec.lftrack = *program;
  spec.shards = o.shards;
  spec.partition = o.partition;
  spec.time_limit = o.time_limit;
  spec.cpus_per_task = o.cpus_per_task;
  spec.study_args = o.study_args;
  LFTRACK_RETURN_IF_ERROR(check_job_array_spec(spec));
  // The study's own parser judges the options every task will get, before anything is queued.
  std::vector<std::string> check{spec.lftrack, "-q", "study", spec.study, "--scene", spec.scenes[0], "--shard",
                                 "1/" + std::to_string(spec.shards), "--check-args"};
  check.insert(check.end(), spec.study_args.begin(), spec.study_args.end());
  std::string said;
  if (!run_process(check, &said).ok())
    return invalid_argument("the study's options after -- do not parse: " + said);
  if (o.dry_run) {
    const char* after[] = {"", "fields", "shards"};
    int n = 0;
    for (const JobScript& j : job_array_scripts(spec)) {
      std::printf("# ---- %s ----\n# sbatch --parsable", j.file.c_str());
      for (const auto& a : j.sbatch) std::printf(" %s", shell_quote(a).c_str());
      if (n > 0) std::printf(" --dependency=afterok:<%s job> --kill-on-invalid-dep=yes", after[n]);
      std::printf(" %s\n%s\n", shell_quote(j.file.string()).c_str(), j.text.c_str());
      ++n;
    }
    std::printf("# dry run: nothing written, nothing submitted\n");
    return {};
  }
  auto jobs = submit_job_array(spec);
  if (!jobs.ok()) return jobs.status();
  std::printf("submitted: fields job %s (%zu tasks), shards job %s (%zu tasks), merge job %s\n", jobs->fields.c_str(),
              spec.scenes.size(), jobs->shards.c_str(), spec.scenes.size() * std::size_t(spec.shards),
              jobs->merge.c_str());
  std::printf("follow it with `lftrack study status %s`; the result will be in %s/merged\n", spec.out_dir.c_str(),
              spec.out_dir.c_str());
  return {};
}

struct StatusCliOptions {
  std::string dir;
  bool json = false;
};

// A shard's state: the task's record, checked against the folder (a "done" shard whose result
// does not read is failed).
// Text from a file, fit for a terminal: at most `max` characters, no control characters.
std::string printable(const std::string& text, std::size_t max) {
  std::string out = text.substr(0, max);
  for (char& c : out)
    if (std::iscntrl(static_cast<unsigned char>(c))) c = ' ';
  return out;
}

ShardTask shard_state(const std::string& study, const fs::path& dir) {
  ShardTask t = read_shard_task(dir);
  t.host = printable(t.host, 64);
  t.slurm_job = printable(t.slurm_job, 32);
  if (t.phase != ShardPhase::kDone) return t;
  const Status readable = study == "trade"     ? read_trade_shard(dir).status()
                          : study == "realism" ? read_realism_shard(dir).status()
                                               : read_capture_range_shard(dir).status();
  if (!readable.ok()) {
    t.phase = ShardPhase::kFailed;
    t.message = "result unreadable: " + readable.message();
  }
  return t;
}

Status run_status(const StatusCliOptions& o) {
  const fs::path record = fs::path(o.dir) / "submit.json";
  std::ifstream in(record);
  if (!in) return not_found(record.string() + ": no such file (not a folder of `lftrack study submit`?)");
  nlohmann::json submitted;
  try {
    submitted = nlohmann::json::parse(in);
    const auto& spec = submitted.at("spec");
    const std::string study = spec.at("study").get<std::string>();
    const auto names = spec.at("scene_names").get<std::vector<std::string>>();
    const auto shards64 = spec.at("shards").get<std::int64_t>();
    if (shards64 < 1 || shards64 > 10000 || names.empty() || names.size() * std::size_t(shards64) > 1000)
      return corrupt_data(record.string() + ": shards or scenes out of range");
    const int shards = int(shards64);
    for (const std::string& name : names)
      if (folder_safe_name(name) != name) return corrupt_data(record.string() + ": scene name '" + name + "' is not a folder name");
    const double now =
        std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
    int counts[4] = {0, 0, 0, 0};
    nlohmann::json rows = nlohmann::json::array();
    if (!o.json) std::printf("%-20s %-12s %-8s %-14s %-16s %9s  %s\n", "scene", "shard", "state", "slurm job", "host",
                             "seconds", "note");
    for (const std::string& name : names) {
      for (int k = 1; k <= shards; ++k) {
        const fs::path dir = shard_dir(o.dir, name, k, shards);
        const ShardTask t = shard_state(study, dir);
        ++counts[int(t.phase)];
        double seconds = t.started_unix_s <= 0 ? 0
                         : t.finished_unix_s > 0 ? t.finished_unix_s - t.started_unix_s
                                                 : now - t.started_unix_s;
        if (!std::isfinite(seconds) || seconds < 0 || seconds > 1e9) seconds = 0;  // a hand-edited record
        const std::string note = printable(t.message, 300);  // from a file: nothing raw to the terminal
        const std::string shard = std::to_string(k) + "/" + std::to_string(shards);
        rows.push_back({{"scene", name},
                        {"shard", shard},
                        {"state", to_string(t.phase)},
                        {"slurm_job", t.slurm_job},
                        {"host", t.host},
                        {"seconds", seconds},
                        {"note", note},
                        {"dir", dir.string()}});
        if (!o.json)
          std::printf("%-20s %-12s %-8s %-14s %-16s %9.0f  %s\n", name.c_str(), shard.c_str(), to_string(t.phase),
                      t.slurm_job.empty() ? "-" : t.slurm_job.c_str(), t.host.empty() ? "-" : t.host.c_str(),
                      seconds, note.c_str());
      }
    }
    std::error_code ec;
    const fs::path merged = fs::path(o.dir) / "merged";
    // What a merge writes last: a realism study's summary, the others' description.
    const std::string last = study == "realism" ? "summary.json" : "study.json";
    const bool is_merged = fs::exists(names.size() > 1 ? merged / "pooled" / last : merged / last, ec);
    if (o.json) {
      std::printf("%s\n", nlohmann::json{{"study", study},
                                         {"shards", rows},
                                         {"done", counts[int(ShardPhase::kDone)]},
                                         {"running", counts[int(ShardPhase::kRunning)]},
                                         {"failed", counts[int(ShardPhase::kFailed)]},
                                         {"pending", counts[int(ShardPhase::kPending)]},
                                         {"merged", is_merged},
                                         {"submissions", submitted.value("submissions", nlohmann::json::array())}}
                                  .dump(2)
                                  .c_str());
      return {};
    }
    std::printf("%s study: %d done, %d running, %d failed, %d pending of %zu shards; %s\n", study.c_str(),
                counts[int(ShardPhase::kDone)], counts[int(ShardPhase::kRunning)], counts[int(ShardPhase::kFailed)],
                counts[int(ShardPhase::kPending)], names.size() * std::size_t(shards),
                is_merged ? ("merged in " + merged.string()).c_str() : "not merged yet");
    if (counts[int(ShardPhase::kFailed)] > 0)
      std::printf("failed shards: read their logs in %s/slurm/logs; `lftrack study submit` with the same "
                  "arguments runs only what is missing\n",
                  o.dir.c_str());
  } catch (const std::exception& e) {
    return corrupt_data(record.string() + ": " + e.what());
  }
  return {};
}

}  // namespace

Command add_study_submit_command(CLI::App* parent) {
  auto* app = parent->add_subcommand(
      "submit",
      "Run a sharded study as a cluster job array: the light fields once, the shards, then the merge");
  auto o = std::make_shared<SubmitCliOptions>();
  app->add_option("--scheduler", o->scheduler, "Cluster scheduler (slurm)")->required();
  app->add_option("--study", o->study, "trade, capture-range or realism")->required();
  app->add_option("--scene", o->scenes, "Scene file; repeat once per patient")->required();
  app->add_option("--out", o->out_dir, "Output folder: fields/, shards/, merged/, slurm/ and submit.json")
      ->required();
  app->add_option("--shards", o->shards, "Shards per scene (array tasks)")->required()->check(CLI::Range(1, 10000));
  app->add_option("--partition", o->partition, "Slurm partition (default: the cluster's)");
  app->add_option("--time", o->time_limit, "Time limit of each task, [D-]HH:MM:SS");
  app->add_option("--cpus-per-task", o->cpus_per_task, "CPUs of each task (its worker threads)")
      ->check(CLI::Range(1, 1024))
      ->capture_default_str();
  app->add_flag("--dry-run", o->dry_run, "Print the scripts and sbatch commands; write and submit nothing");
  app->add_option("study_args", o->study_args, "After --: options for every task of the study (e.g. -- --quick)");
  return [o]() { return run_submit(*o); };
}

Command add_study_status_command(CLI::App* parent) {
  auto* app = parent->add_subcommand("status", "Shards of a submitted study: done, running, failed, pending");
  auto o = std::make_shared<StatusCliOptions>();
  app->add_option("dir", o->dir, "The study's --out folder")->required();
  app->add_flag("--json", o->json, "Print the status as JSON");
  return [o]() { return run_status(*o); };
}

}  // namespace lftrack::cli
