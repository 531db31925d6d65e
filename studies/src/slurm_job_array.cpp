#include "lftrack/studies/slurm_job_array.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>

#include "lftrack/studies/plastimatch_peer.hpp"  // run_process
#include "lftrack/studies/study_shard.hpp"

namespace lftrack::studies {
namespace {

// Options every task sets itself; a user's copy would contradict the job's layout.
const std::set<std::string>& reserved_options() {
  static const std::set<std::string> reserved{"--scene", "--shard", "--out", "--lf-dir", "--fields-prebuilt",
                                              "--build-fields", "--threads", "--ct", "--list", "--check-args",
                                              "-h", "--help"};
  return reserved;
}

std::string bash_array(const std::vector<std::string>& words) {
  std::string s = "(";
  for (std::size_t i = 0; i < words.size(); ++i) {
    if (i) s += ' ';
    s += shell_quote(words[i]);
  }
  s += ')';
  return s;
}

std::string joined_args(const std::vector<std::string>& args) {
  std::string s;
  for (const auto& a : args) s += " " + shell_quote(a);
  return s;
}

// The lines every script starts with: what it is, strict bash, the arrays of scenes and names.
std::string preamble(const JobArraySpec& spec, const std::string& what) {
  return "#!/bin/bash\n# lftrack study submit: " + what + "\n# Generated for " + spec.out_dir.string() +
         "; submitted by sbatch with the options in submit.json.\nset -euo pipefail\nscenes=" +
         bash_array(spec.scenes) + "\nnames=" + bash_array(spec.scene_names) + "\n";
}

std::vector<std::string> common_sbatch(const JobArraySpec& spec, const std::string& name) {
  std::vector<std::string> o{"--job-name=lftrack-" + spec.study + "-" + name,
                             "--chdir=" + spec.work_dir.string(),
                             "--cpus-per-task=" + std::to_string(spec.cpus_per_task)};
  if (!spec.partition.empty()) o.push_back("--partition=" + spec.partition);
  if (!spec.time_limit.empty()) o.push_back("--time=" + spec.time_limit);
  return o;
}

nlohmann::json spec_json(const JobArraySpec& s) {
  return {{"study", s.study}, {"scenes", s.scenes},       {"scene_names", s.scene_names},
          {"shards", s.shards}, {"study_args", s.study_args}};
}

// The job id in sbatch --parsable's output ("123" or "123;cluster"), ignoring warnings.
Result<std::string> parse_job_id(const std::string& output) {
  std::istringstream in(output);
  std::string line, id;
  static const std::regex parsable(R"(^([0-9]+)(;\S+)?\s*$)");
  while (std::getline(in, line)) {
    std::smatch m;
    if (std::regex_match(line, m, parsable)) id = m[1];
  }
  if (id.empty()) return internal_error("sbatch printed no job id: " + output);
  return id;
}

}  // namespace

std::string folder_safe_name(const std::string& scene_name) {
  std::string name = scene_name.substr(0, 100);
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '.' && c != '_' && c != '-') c = '_';
  if (name.empty() || name[0] == '.') name = ("scene" + name).substr(0, 100);
  return name;
}

std::string shell_quote(const std::string& word) {
  std::string s = "'";
  for (char c : word) s += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return s + "'";
}

std::filesystem::path shard_dir(const std::filesystem::path& out_dir, const std::string& scene_name, int k, int n) {
  return out_dir / "shards" / scene_name / ("shard-" + std::to_string(k) + "-of-" + std::to_string(n));
}

Status check_job_array_spec(const JobArraySpec& spec) {
  if (spec.study != "trade" && spec.study != "capture-range" && spec.study != "realism")
    return invalid_argument("--study '" + spec.study + "': expected trade, capture-range or realism");
  if (spec.scenes.empty()) return invalid_argument("no scene given (--scene FILE, once per patient)");
  if (spec.scene_names.size() != spec.scenes.size()) return internal_error("a name per scene is needed");
  static const std::regex safe_name(R"(^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$)");
  std::set<std::string> names;
  for (std::size_t i = 0; i < spec.scenes.size(); ++i) {
    const std::string& n = spec.scene_names[i];
    if (!std::regex_match(n, safe_name))
      return invalid_argument("scene " + spec.scenes[i] + ": its name '" + n +
                              "' cannot name a folder (letters, digits, '.', '_', '-'; up to 100)");
    if (!names.insert(n).second)
      return invalid_argument("two scenes are named '" + n + "'; each patient's scene needs its own name");
    if (n == "pooled") return invalid_argument("scene " + spec.scenes[i] + ": 'pooled' names the pooled study's folder");
  }
  if (spec.shards < 1 || spec.shards > 10000) return out_of_range("--shards must be in [1, 10000]");
  // Slurm's default MaxArraySize is 1001 (task ids 0-1000); the merge job lists every shard.
  if (std::size_t(spec.shards) * spec.scenes.size() > 1000)
    return out_of_range("scenes x shards is " + std::to_string(std::size_t(spec.shards) * spec.scenes.size()) +
                        " array tasks; at most 1000 (Slurm's default MaxArraySize is 1001)");
  // Paths go into scripts and sbatch options: no control characters anywhere (a newline would
  // end a line of the script), and no '%' or '\\' in the output folder (sbatch expands them in
  // --output).
  auto has_control = [](const std::string& text) {
    return std::any_of(text.begin(), text.end(), [](char c) { return std::iscntrl(static_cast<unsigned char>(c)); });
  };
  for (const std::string& path : {spec.out_dir.string(), spec.work_dir.string(), spec.lftrack})
    if (has_control(path)) return invalid_argument("a path (output, work folder or program) holds a control character");
  for (const std::string& scene : spec.scenes)
    if (has_control(scene)) return invalid_argument("the scene path holds a control character");
  for (const std::string& a : spec.study_args)
    if (has_control(a)) return invalid_argument("a study argument holds a control character");
  if (spec.out_dir.string().find_first_of("%\\") != std::string::npos)
    return invalid_argument("--out " + spec.out_dir.string() + ": '%' and '\\' are not allowed (sbatch expands them)");
  if (spec.cpus_per_task < 1 || spec.cpus_per_task > 1024) return out_of_range("--cpus-per-task must be in [1, 1024]");
  static const std::regex time_form(R"(^([0-9]{1,3}-)?[0-9]{1,3}:[0-5][0-9]:[0-5][0-9]$)");
  if (!spec.time_limit.empty() && !std::regex_match(spec.time_limit, time_form))
    return invalid_argument("--time '" + spec.time_limit + "': expected [D-]HH:MM:SS");
  static const std::regex partition_form(R"(^[A-Za-z0-9._-]{1,64}$)");
  if (!spec.partition.empty() && !std::regex_match(spec.partition, partition_form))
    return invalid_argument("--partition '" + spec.partition + "': not a partition name");
  for (const std::string& a : spec.study_args) {
    const std::string option = a.substr(0, a.find('='));
    if (reserved_options().count(option))
      return invalid_argument("study argument '" + a + "': the jobs set " + option + " themselves");
  }
  if (!spec.out_dir.is_absolute() || !spec.work_dir.is_absolute() || spec.lftrack.empty() || spec.lftrack[0] != '/')
    return internal_error("the output folder, work folder and program must be absolute paths");
  return {};
}

std::vector<JobScript> job_array_scripts(const JobArraySpec& spec) {
  const std::string out = spec.out_dir.string();
  const std::string lftrack = shell_quote(spec.lftrack);
  const std::string args = joined_args(spec.study_args);
  const std::string logs = (spec.out_dir / "slurm" / "logs").string();
  const int scenes = int(spec.scenes.size());
  std::vector<JobScript> jobs;

  JobScript fields;
  fields.name = "fields";
  fields.array_size = scenes;
  fields.text = preamble(spec, "build the light fields of each scene once (one task per scene)") +
                "i=${SLURM_ARRAY_TASK_ID:?run this as a task of sbatch --array}\n"
                "exec " + lftrack + " study " + spec.study +
                " --scene \"${scenes[$i]}\" --threads \"${SLURM_CPUS_PER_TASK:-0}\" --build-fields --lf-dir " +
                shell_quote(out + "/fields/") + "\"${names[$i]}\"" + args + "\n";
  jobs.push_back(fields);

  JobScript shards;
  shards.name = "shards";
  shards.array_size = scenes * spec.shards;
  shards.text = preamble(spec, "one shard of one scene per task (scenes x shards tasks)") +
                "n=" + std::to_string(spec.shards) +
                "\ni=${SLURM_ARRAY_TASK_ID:?run this as a task of sbatch --array}\n"
                "p=$(( i / n ))\nk=$(( i % n + 1 ))\n"
                "exec " + lftrack + " study " + spec.study +
                " --scene \"${scenes[$p]}\" --threads \"${SLURM_CPUS_PER_TASK:-0}\" --shard \"$k/$n\" --out " +
                shell_quote(out + "/shards/") + "\"${names[$p]}/shard-$k-of-$n\" --lf-dir " +
                shell_quote(out + "/fields/") + "\"${names[$p]}\" --fields-prebuilt" + args + "\n";
  jobs.push_back(shards);

  JobScript merge;
  merge.name = "merge";
  std::vector<std::string> dirs;
  for (std::size_t p = 0; p < spec.scenes.size(); ++p)
    for (int k = 1; k <= spec.shards; ++k) dirs.push_back(shard_dir(spec.out_dir, spec.scene_names[p], k, spec.shards).string());
  merge.text = preamble(spec, "join every shard; per scene and pooled when there are several") +
               "shard_dirs=" + bash_array(dirs) + "\nexec " + lftrack + " study merge --out " +
               shell_quote(out + "/merged") + " \"${shard_dirs[@]}\"\n";
  jobs.push_back(merge);

  for (JobScript& j : jobs) {
    j.file = spec.out_dir / "slurm" / (j.name + ".sh");
    j.sbatch = common_sbatch(spec, j.name);
    if (j.array_size > 0) {
      j.sbatch.push_back("--array=0-" + std::to_string(j.array_size - 1));
      j.sbatch.push_back("--output=" + logs + "/" + j.name + "-%A_%a.log");
    } else {
      j.sbatch.push_back("--output=" + logs + "/" + j.name + "-%j.log");
    }
  }
  return jobs;
}

Result<SubmittedJobs> submit_job_array(const JobArraySpec& spec) {
  LFTRACK_RETURN_IF_ERROR(check_job_array_spec(spec));
  const auto record = spec.out_dir / "submit.json";
  nlohmann::json history = nlohmann::json::array();
  {
    std::ifstream in(record);
    if (in) {
      nlohmann::json earlier;
      try {
        earlier = nlohmann::json::parse(in);
      } catch (const std::exception& e) {
        return corrupt_data(record.string() + ": " + e.what() + "; not submitting over it");
      }
      if (!earlier.contains("spec") || earlier["spec"] != spec_json(spec))
        return failed_precondition(record.string() + " records another submission (" +
                                   (earlier.contains("spec") ? earlier["spec"].dump() : std::string("unknown")) +
                                   "); choose another --out");
      history = earlier.value("submissions", nlohmann::json::array());
      if (!history.is_array())
        return corrupt_data(record.string() + ": 'submissions' is not a list; not submitting over it");
    }
  }
  std::error_code ec;
  std::filesystem::create_directories(spec.out_dir / "slurm" / "logs", ec);
  if (ec) return io_error((spec.out_dir / "slurm").string() + ": cannot create folder: " + ec.message());
  // The record first (another submit into this folder is then refused even if sbatch fails below).
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(
      record, nlohmann::json{{"spec", spec_json(spec)}, {"out_dir", spec.out_dir.string()},
                             {"lftrack", spec.lftrack}, {"submissions", history}}
                      .dump(2) + "\n"));
  const auto jobs = job_array_scripts(spec);
  for (const JobScript& j : jobs) {
    LFTRACK_RETURN_IF_ERROR(write_file_atomically(j.file, j.text));
    std::filesystem::permissions(j.file, std::filesystem::perms::owner_exec, std::filesystem::perm_options::add, ec);
  }
  SubmittedJobs ids;
  std::string previous;
  for (const JobScript& j : jobs) {
    std::vector<std::string> argv{"sbatch", "--parsable"};
    argv.insert(argv.end(), j.sbatch.begin(), j.sbatch.end());
    if (!previous.empty()) {
      // A failed earlier job cancels this one rather than leaving it pending for ever.
      argv.push_back("--dependency=afterok:" + previous);
      argv.push_back("--kill-on-invalid-dep=yes");
    }
    argv.push_back(j.file.string());
    std::string output;
    const Status s = run_process(argv, &output);
    if (!s.ok()) {
      // The jobs already queued would wait for a chain that never comes: cancel them.
      std::string cancelled;
      for (const std::string& id : {ids.fields, ids.shards})
        if (!id.empty()) {
          std::string ignored;
          (void)run_process({"scancel", id}, &ignored);
          cancelled += " " + id;
        }
      return internal_error("sbatch refused the " + j.name + " job" +
                            (cancelled.empty() ? "" : " (cancelled the jobs already queued:" + cancelled + ")") +
                            ": " + output);
    }
    auto id = parse_job_id(output);
    if (!id.ok()) return id.status();
    (j.name == "fields" ? ids.fields : j.name == "shards" ? ids.shards : ids.merge) = *id;
    previous = *id;
  }
  const double now =
      std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  history.push_back({{"submitted_unix_s", now},
                     {"fields_job", ids.fields},
                     {"shards_job", ids.shards},
                     {"merge_job", ids.merge}});
  nlohmann::json j = {{"spec", spec_json(spec)},
                      {"out_dir", spec.out_dir.string()},
                      {"lftrack", spec.lftrack},
                      {"submissions", history}};
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(record, j.dump(2) + "\n"));
  return ids;
}

}  // namespace lftrack::studies
