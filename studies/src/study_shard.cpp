#include "lftrack/studies/study_shard.hpp"

#include <nlohmann/json.hpp>
#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "lftrack/tracking/light_field.hpp"

namespace lftrack::studies {

using session::PreparedScene;
using session::RegistrationSpec;
using session::VerdictChecksSpec;
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
  // The temporary name carries host and pid: tasks on two hosts of a shared file system, or two
  // processes here, never write the same temporary file.
  std::string partial_name = ".";
  partial_name += file.filename().string();
  partial_name += '.';
  partial_name += this_host();
  partial_name += '.';
  partial_name += std::to_string(getpid());
  partial_name += ".partial";
  const std::filesystem::path partial = file.parent_path() / partial_name;
  const int fd = open(partial.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return io_error(partial.string() + ": cannot open for writing: " + std::strerror(errno));
  std::size_t written = 0;
  bool ok = true;
  while (ok && written < text.size()) {
    const ssize_t n = write(fd, text.data() + written, text.size() - written);
    if (n < 0 && errno == EINTR) continue;
    ok = n > 0;
    if (ok) written += std::size_t(n);
  }
  const int write_errno = errno;
  // On the disk before the rename: a crash leaves the old file or the whole new one.
  ok = ok && fsync(fd) == 0;
  ok = close(fd) == 0 && ok;
  std::error_code ec;
  if (!ok) {
    std::filesystem::remove(partial, ec);
    return io_error(file.string() + ": write failed: " + std::strerror(write_errno ? write_errno : EIO));
  }
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
  // Two tasks on one shard at once (a resubmission while the first still runs) would interleave
  // their files: a live task here is left alone. One on another host cannot be asked; say so.
  const ShardTask current = read_shard_task(dir);
  if (current.phase == ShardPhase::kRunning && current.host == this_host() && current.pid != getpid())
    return failed_precondition(dir.string() + ": another task (pid " + std::to_string(current.pid) +
                               (current.slurm_job.empty() ? "" : ", Slurm job " + current.slurm_job) +
                               ") is computing this shard; not starting a second one");
  if (current.phase == ShardPhase::kRunning && current.host != this_host())
    note += (note.empty() ? "" : "; ") + std::string("a task on ") + current.host +
            " was recorded running this shard; computing it here";
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

std::string study_scene_fingerprint(const PreparedScene& p) {
  // FNV-1a over the volumes' and views' identities and what registers and renders the frames.
  std::uint64_t h = 1469598103934665603ull;
  auto mix = [&](std::uint64_t v) {
    for (int i = 0; i < 8; ++i) {
      h ^= (v >> (8 * i)) & 0xffu;
      h *= 1099511628211ull;
    }
  };
  auto mix_text = [&](const std::string& text) {
    for (unsigned char c : text) mix(c);
    mix(0xff);
  };
  if (p.mu) mix(tracking::volume_hash(*p.mu));
  if (p.world_mu) mix(tracking::volume_hash(*p.world_mu));
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i)
    mix(tracking::plan_hash(p.light_field_plan(int(i)), p.scene.light_field));
  const RegistrationSpec& r = p.scene.registration;
  mix_text(r.similarity);
  mix_text(r.plan);
  mix_text(p.scene.sim.renderer);
  mix(std::uint64_t(std::llround(p.scene.sim.photons_per_pixel)));
  mix(std::uint64_t(std::llround(p.scene.sim.detector_blur_px * 1e6)));
  // What judges the results: the verdict's floors (a commissioning file's bytes, or the scene's
  // own floor), its edge band and view check, and the tolerance that says a result is right.
  const auto micro = [](double x) { return std::uint64_t(std::llround(x * 1e6)); };
  if (!p.scene.commissioning_file.empty()) {
    std::ifstream in(p.scene.commissioning_file, std::ios::binary);
    std::ostringstream bytes;
    bytes << in.rdbuf();
    mix_text(bytes.str());
  }
  mix(p.scene.min_similarity_given ? micro(p.scene.safety.min_similarity) : 0);
  const VerdictChecksSpec& checks = p.scene.verdict_checks;
  for (double x : {checks.envelope_edge_mm, checks.envelope_edge_deg, checks.max_view_shift_mm,
                   p.scene.safety.beam_tolerance_mm})
    mix(micro(x));
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(h));
  return hex;
}

Status check_shard_position(std::int64_t shard, std::int64_t shards, const std::filesystem::path& file) {
  if (shards < 1 || shards > 10000 || shard < 1 || shard > shards)
    return corrupt_data(file.string() + ": shard k/n out of range");
  return {};
}

}  // namespace lftrack::studies
