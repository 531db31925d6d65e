#pragma once
// A sharded study as Slurm jobs (issue 25): `lftrack study submit --scheduler slurm`.
//
// Three jobs, each a bash script run by sbatch:
//   1. fields  (array, one task per scene): builds the light fields the study needs once, into
//      OUT/fields/<scene>/; later tasks map those files read-only and never build.
//   2. shards  (array of scenes x shards, after fields succeeded): task i runs
//      `lftrack study <study> --scene S --shard k/N --out OUT/shards/<scene>/shard-k-of-N`; a task
//      whose shard is already complete exits 0 at once (study_shard.hpp).
//   3. merge   (after every shard succeeded): `lftrack study merge --out OUT/merged` over every
//      shard folder; with several scenes, one folder per scene and the pooled study.
// OUT/submit.json records what was submitted and the job ids; the scripts and their logs live in
// OUT/slurm/. Nothing here talks to Slurm except submit_job_array, which runs sbatch.

#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"

namespace lftrack::studies {

struct JobArraySpec {
  std::string study;                        // "trade" or "capture-range"
  std::vector<std::string> scenes;          // scene files (absolute) or builtin:NAME, one per patient
  std::vector<std::string> scene_names;     // the scenes' names (folder names under shards/), unique
  std::filesystem::path out_dir;            // absolute
  std::filesystem::path work_dir;           // where the jobs run (absolute)
  std::string lftrack;                      // the program, absolute
  int shards = 1;                           // per scene
  std::string partition;                    // empty: the cluster's default
  std::string time_limit;                   // HH:MM:SS or empty
  int cpus_per_task = 2;
  std::vector<std::string> study_args;      // given to every task of the study (--quick, --seed ...)
};

// Checks a spec before anything is written: known study, scenes with unique, path-safe names,
// 1 <= shards <= 10000, 1 <= cpus <= 1024, a time limit of the form [D-]HH:MM:SS, and study
// arguments that are not the ones the jobs set themselves (--scene, --shard, --out, --lf-dir...).
Status check_job_array_spec(const JobArraySpec& spec);

struct JobScript {
  std::string name;                // "fields", "shards", "merge"
  std::filesystem::path file;      // OUT/slurm/<name>.sh
  std::string text;                // the bash script
  std::vector<std::string> sbatch; // sbatch's options (the dependency is added at submission)
  int array_size = 0;              // 0: not an array
};

// The three scripts and their sbatch options.
std::vector<JobScript> job_array_scripts(const JobArraySpec& spec);

// The folder of shard k (1-based) of scene `name`.
std::filesystem::path shard_dir(const std::filesystem::path& out_dir, const std::string& scene_name, int k, int n);

struct SubmittedJobs {
  std::string fields, shards, merge;  // job ids
};

// Writes the scripts and OUT/submit.json, then submits them with `sbatch` (found on PATH), each
// after the one before (--dependency=afterok). A folder that holds another submission (another
// study, scenes, shard count or arguments) is refused; the same one is submitted again (its
// tasks finish only what is missing).
Result<SubmittedJobs> submit_job_array(const JobArraySpec& spec);

// A scene's name as a folder name: letters, digits, '.', '_' and '-' kept, anything else '_',
// at most 100 characters, never starting with '.'.
std::string folder_safe_name(const std::string& scene_name);

// Single-quotes `word` for bash.
std::string shell_quote(const std::string& word);

}  // namespace lftrack::studies
