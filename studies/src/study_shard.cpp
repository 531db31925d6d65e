#include "lftrack/studies/study_shard.hpp"

#include <nlohmann/json.hpp>
#include <signal.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <fstream>
#include <sstream>

namespace lftrack::host {
namespace {

constexpr const char* kTaskFile = "task.json";

std::string this_host() {
  char name[256] = {};
  if (gethostname(name, sizeof name - 1) != 0) return "unknown";
  return name;
}

double now_unix_s() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

ShardPhase phase_from(const std::string& text) {
  if (text == "running") return ShardPhase::kRunning;
  if (text == "done") return ShardPhase::kDone;
  if (text == "failed") return ShardPhase::kFailed;
  return ShardPhase::kPending;
}

// True when no process `pid` exists on this host (EPERM means it exists, owned by another user).
bool process_gone(std::int64_t pid) {
  if (pid <= 0 || pid > 0x7fffffff) return true;
  return kill(pid_t(pid), 0) != 0 && errno == ESRCH;
}

}  // namespace

const char* to_string(ShardPhase phase) {
  switch (phase) {
    case ShardPhase::kPending:
      return "pending";
    case ShardPhase::kRunning:
      return "running";
    case ShardPhase::kDone:
      return "done";
    case ShardPhase::kFailed:
      return "failed";
  }
  return "pending";
}

std::string slurm_job_from_environment() {
  const char* array_job = std::getenv("SLURM_ARRAY_JOB_ID");
  const char* array_task = std::getenv("SLURM_ARRAY_TASK_ID");
  if (array_job && array_task && *array_job && *array_task) return std::string(array_job) + "_" + array_task;
  const char* job = std::getenv("SLURM_JOB_ID");
  return job && *job ? job : "";
}

Status write_file_atomically(const std::filesystem::path& file, const std::string& text) {
  std::string partial_name = ".";
  partial_name += file.filename().string();
  partial_name += '.';
  partial_name += std::to_string(getpid());
  partial_name += ".partial";
  const std::filesystem::path partial = file.parent_path() / partial_name;
  {
    std::ofstream out(partial, std::ios::binary | std::ios::trunc);
    if (!out) return io_error(partial.string() + ": cannot open for writing");
    out << text;
    out.flush();
    if (!out) {
      std::error_code ignored;
      std::filesystem::remove(partial, ignored);
      return io_error(partial.string() + ": write failed (disk full?)");
    }
  }
  std::error_code ec;
  std::filesystem::rename(partial, file, ec);
  if (ec) {
    std::filesystem::remove(partial, ec);
    return io_error(file.string() + ": cannot move the new file into place");
  }
  return {};
}

ShardTask read_shard_task(const std::filesystem::path& dir) {
  ShardTask t;
  std::ifstream in(dir / kTaskFile);
  if (!in) return t;
  try {
    const auto j = nlohmann::json::parse(in);
    t.phase = phase_from(j.value("phase", ""));
    t.host = j.value("host", "");
    t.pid = j.value("pid", std::int64_t{0});
    t.slurm_job = j.value("slurm_job", "");
    t.started_unix_s = j.value("started_unix_s", 0.0);
    t.finished_unix_s = j.value("finished_unix_s", 0.0);
    t.message = j.value("message", "");
  } catch (const std::exception& e) {
    t.phase = ShardPhase::kFailed;
    t.message = (dir / kTaskFile).string() + " does not parse: " + e.what();
    return t;
  }
  if (t.phase == ShardPhase::kRunning && t.host == this_host() && process_gone(t.pid)) {
    t.phase = ShardPhase::kFailed;
    t.message = "the task's process (" + std::to_string(t.pid) + ") is gone without a result";
  }
  return t;
}

Status record_shard_task(const std::filesystem::path& dir, ShardPhase phase, const std::string& message,
                         double started_unix_s) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return io_error(dir.string() + ": cannot create folder: " + ec.message());
  const double now = now_unix_s();
  nlohmann::json j;
  j["phase"] = to_string(phase);
  j["host"] = this_host();
  j["pid"] = std::int64_t(getpid());
  j["slurm_job"] = slurm_job_from_environment();
  j["started_unix_s"] = phase == ShardPhase::kRunning || started_unix_s <= 0 ? now : started_unix_s;
  j["finished_unix_s"] = phase == ShardPhase::kRunning ? 0.0 : now;
  j["message"] = message;
  return write_file_atomically(dir / kTaskFile, j.dump(2) + "\n");
}

Status run_shard_task(const std::filesystem::path& dir, const std::function<Status()>& check_complete,
                      const std::function<Status()>& run, std::string* said) {
  std::string note;
  std::error_code ec;
  if (std::filesystem::exists(dir / "study.json", ec)) {
    const Status complete = check_complete();
    if (complete.ok()) {
      if (read_shard_task(dir).phase != ShardPhase::kDone)
        LFTRACK_RETURN_IF_ERROR(record_shard_task(dir, ShardPhase::kDone, "found complete"));
      if (said) *said = dir.string() + " already holds this shard's complete result; nothing to do";
      return {};
    }
    if (complete.code() == StatusCode::kFailedPrecondition)
      return failed_precondition(complete.message() + "; refusing to overwrite it (choose another --out)");
    note = "the result there is incomplete (" + complete.message() + "); computing it again";
  }
  const double started = now_unix_s();
  LFTRACK_RETURN_IF_ERROR(record_shard_task(dir, ShardPhase::kRunning, note));
  const Status s = run();
  if (!s.ok()) {
    // The failure is what the caller reports; a record that cannot be written changes nothing.
    (void)record_shard_task(dir, ShardPhase::kFailed, s.message(), started);
    return s;
  }
  LFTRACK_RETURN_IF_ERROR(record_shard_task(dir, ShardPhase::kDone, note, started));
  if (said) *said = note;
  return {};
}

}  // namespace lftrack::host
