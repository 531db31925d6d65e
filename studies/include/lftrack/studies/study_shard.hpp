#pragma once
// What a study's shard folder says about itself, for job arrays (issue 25).
//
// A shard task writes `task.json` into its folder when it starts (running: host, pid, Slurm job),
// when it ends (done) and when it fails (failed, with the error). The shard's results are written
// to temporary names and renamed into place, the study's description (study.json) last, so a
// folder is either complete or visibly not: a task killed halfway leaves no file that a merge
// could take for a result. Whether a shard is *complete* is checked by its study (the trade and
// capture-range readers compare the folder against the shard the task would compute); this file
// only keeps the record of the task.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::studies {

enum class ShardPhase { kPending, kRunning, kDone, kFailed };
const char* to_string(ShardPhase phase);

struct ShardTask {
  ShardPhase phase = ShardPhase::kPending;
  std::string host;         // where the task ran
  std::int64_t pid = 0;     // its process there
  std::string slurm_job;    // "ARRAYJOB_TASK" or "JOB" when run by Slurm; empty otherwise
  double started_unix_s = 0;
  double finished_unix_s = 0;  // 0 while running
  std::string message;         // why it failed; what it did when done
};

// The task's record in `dir`: kPending when there is none. A record that says running on this
// host with a process that no longer exists reads as kFailed ("the task's process is gone").
ShardTask read_shard_task(const std::filesystem::path& dir);

// Records this process as the task of `dir` in `phase` (creates the folder).
Status record_shard_task(const std::filesystem::path& dir, ShardPhase phase, const std::string& message = {},
                         double started_unix_s = 0);

// The Slurm job of this process from the environment ("123_4" for array task 4 of job 123,
// "123" for a plain job), empty outside Slurm.
std::string slurm_job_from_environment();

// Runs one shard task with `dir` as its output folder, idempotently. When `dir` already holds a
// result (study.json), `check_complete` says whether it is this shard's complete result: if so
// nothing runs and the task succeeds (a requeued or resubmitted array only finishes what is
// missing); if it is another study's (kFailedPrecondition), the task refuses rather than
// overwrite it; anything else (a torn or partial result) is computed again. Otherwise `run` is
// called, with the task recorded as running, then done or failed; a task recorded running by a
// live process on this host is not started twice (kFailedPrecondition). `said` (may be null)
// gets what happened, for the user.
Status run_shard_task(const std::filesystem::path& dir, const std::function<Status()>& check_complete,
                      const std::function<Status()>& run, std::string* said = nullptr);

// What a study's results depend on besides its options, as 16 hex digits: the CT (and the
// simulated patient's volume), each view's geometry with the ROI and envelope, the registration's
// measure and plan, and the simulated frames' renderer and noise. Shards with different
// fingerprints are different studies even when their scenes share a name.
std::string study_scene_fingerprint(const session::PreparedScene& scene);

// Writes `text` to `file` through a temporary file in the same folder and a rename: readers see
// the old file or the whole new one, never part of it.
Status write_file_atomically(const std::filesystem::path& file, const std::string& text);

// A shard description's place in its study: `shard` and `shards` as 1 <= shard <= shards <= 10000
// (kCorruptData naming `file` otherwise). The numbers as a description's JSON holds them.
Status check_shard_position(std::int64_t shard, std::int64_t shards, const std::filesystem::path& file);

}  // namespace lftrack::studies
