// `lftrack rt-check` as a user runs it: the JSON report's keys, the scene's priority and CPUs
// taken by default, the histogram and plot files, and every refused option exiting 1 with the
// reason (values out of range: exit 2, Cli/UsageError). Runs are a fraction of a second; no
// latency bound is asserted.

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/rt_check/wakeup_latency.hpp"
#include "lftrack/session/scene.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

using test::CliRun;
using test::quoted;
using test::contents;

namespace fs = std::filesystem;

// `lftrack -q rt-check ARGS`, its exit code and output.
CliRun rt_check(const std::vector<std::string>& args, const fs::path& dir) {
  std::string command = quoted(LFTRACK_BIN_PATH) + " -q rt-check";
  for (const auto& a : args) {
    command += ' ';
    command += quoted(a);
  }
  const fs::path log = dir / "out.txt";
  command += " >";
  command += quoted(log.string());
  command += " 2>&1";
  CliRun r;
  const int status = std::system(command.c_str());
  if (status != -1 && WIFEXITED(status)) r.exit_code = WEXITSTATUS(status);
  std::ifstream in(log);
  r.out.assign(std::istreambuf_iterator<char>(in), {});
  return r;
}

nlohmann::json json_of(const std::string& out) {
  const auto brace = out.find('{');
  if (brace == std::string::npos) return {};
  return nlohmann::json::parse(out.substr(brace, out.rfind('}') - brace + 1));
}

TEST(RtCheckCli, JsonReportCarriesTheFiguresAndTheScenesSettings) {
  test::TempDir dir;
  const CliRun r = rt_check({"--duration", "0.2", "--json", "--load-note", "test"}, dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const nlohmann::json j = json_of(r.out);
  for (const char* key : {"scene", "cycle_period_ms", "interval_us", "planned_s", "priority", "fifo", "pinned",
                          "memory_locked", "vmlck_kb", "in_effect", "budget_us", "budget_from", "cpus_from", "max_us",
                          "max_fraction_of_cycle_percent", "over_budget", "samples", "kernel", "verdict", "cpus"})
    EXPECT_TRUE(j.contains(key)) << key << " in " << r.out;
  // The built-in scene: priority 80 (loop.realtime's default), no CPUs named, a 100 ms cycle whose
  // slack beyond acquisition (40 ms) and registration (50 ms) is 10 ms.
  EXPECT_EQ(j["scene"], "builtin:phantom");
  EXPECT_EQ(j["priority"], 80);
  EXPECT_DOUBLE_EQ(j["cycle_period_ms"].get<double>(), 100.0);
  EXPECT_DOUBLE_EQ(j["budget_us"].get<double>(), 10000.0);
  EXPECT_EQ(j["load_note"], "test");
  EXPECT_EQ(j["cpus"].size(), rt_check::allowed_cpus().size());
  for (const char* key : {"release", "version", "preempt_rt", "model"}) EXPECT_TRUE(j["kernel"].contains(key)) << key;
  for (const auto& c : j["cpus"]) {
    for (const char* key : {"cpu", "samples", "min_us", "mean_us", "p50_us", "p99_us", "p999_us", "max_us",
                            "over_budget", "fifo", "policy", "pinned", "histogram"})
      EXPECT_TRUE(c.contains(key)) << key;
    EXPECT_EQ(c["samples"].get<std::int64_t>() + c["skipped_periods"].get<std::int64_t>(), 200);
    EXPECT_LE(c["min_us"].get<double>(), c["p50_us"].get<double>());
    EXPECT_LE(c["p50_us"].get<double>(), c["p99_us"].get<double>());
    EXPECT_LE(c["p99_us"].get<double>(), c["max_us"].get<double>());
  }
  const std::string verdict = j["verdict"];
  EXPECT_NE(verdict.find("of the 100 ms cycle"), std::string::npos) << verdict;
  EXPECT_NE(verdict.find("PREEMPT_RT"), std::string::npos) << verdict;
  EXPECT_NE(verdict.find(j["fifo"].get<bool>() ? "SCHED_FIFO 80" : "NOT real-time"), std::string::npos) << verdict;
}

TEST(RtCheckCli, TakesTheScenesPriorityAndCpusAndWritesTheHistogramAndPlot) {
  test::TempDir dir;
  const int cpu = rt_check::allowed_cpus().back();
  std::string scene = *builtin_scene_text(kBuiltinPhantom);
  const std::string rt = "    mode: ignore          # a treatment-room host sets enforce and cpus\n";
  ASSERT_NE(scene.find(rt), std::string::npos);
  scene.replace(scene.find(rt), rt.size(), "    mode: ignore\n    priority: 42\n    cpus: [" + std::to_string(cpu) + "]\n");
  const fs::path file = dir.path() / "rt.yaml";
  std::ofstream(file) << scene;
  const fs::path csv = dir.path() / "hist.csv", png = dir.path() / "hist.png";
  const CliRun r = rt_check({"--scene", file.string(), "--duration", "0.1", "--interval-us", "500", "--histogram",
                             csv.string(), "--plot", png.string()},
                            dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("verdict: max "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("SCHED_FIFO 42 requested on CPU " + std::to_string(cpu) + " (the scene's loop.realtime.cpus)"), std::string::npos) << r.out;
  std::ifstream in(csv);
  std::string line, header;
  std::getline(in, line);
  EXPECT_EQ(line.rfind("# lftrack rt-check", 0), 0u) << line;
  std::getline(in, header);
  EXPECT_EQ(header, "latency_us,cpu" + std::to_string(cpu));
  std::uint64_t sum = 0;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    sum += std::stoull(line.substr(line.find(',') + 1));  // the overflow comment's count included
  }
  EXPECT_LE(sum, 200u);  // 0.1 s of 500 us wake-ups, less any skipped
  EXPECT_GE(sum, 100u);
  EXPECT_TRUE(fs::exists(dir.path() / "hist.gp"));
  EXPECT_TRUE(fs::exists(dir.path() / "hist.dat"));
  if (std::system("command -v gnuplot >/dev/null 2>&1") == 0) {
    EXPECT_GT(fs::file_size(png), 1000u);
  }
}

// What the parser cannot judge is refused after it with exit 1 and the reason: the host's CPUs,
// two values together, the files. (Values out of range exit 2: Cli/UsageError.)
TEST(RtCheckCli, RefusedOptionsExitOneWithTheReason) {
  test::TempDir dir;
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"--duration", "0.0001", "--interval-us", "1000"}, "shorter than one interval"},
      {{"--cpus", "4000"}, "does not exist"},
      {{"--cpus", "0,0"}, "named twice"},
      {{"--plot", (dir.path() / "plot.svg").string()}, ".png"},
      {{"--histogram", (dir.path() / "missing" / "h.csv").string()}, "does not exist"},
  };
  for (const auto& [args, says] : cases) {
    std::vector<std::string> argv = args;
    if (args[0] != "--duration") argv.insert(argv.end(), {"--duration", "0.05"});
    const CliRun r = rt_check(argv, dir.path());
    EXPECT_EQ(r.exit_code, 1) << args[0] << " " << args[1] << ": " << r.out;
    EXPECT_NE(r.out.find(says), std::string::npos) << args[0] << " " << args[1] << ": " << r.out;
    EXPECT_EQ(r.out.find("verdict"), std::string::npos) << "nothing measured: " << r.out;
  }
}

// --histogram and --plot never replace a file without --overwrite (an outside probe saw a file
// replaced), refused before measuring; and a write that fails is an error with its reason (the
// probe saw success reported for /dev/full).
TEST(RtCheckCli, ReportFilesAreReplacedOnlyWithOverwriteAndAFailedWriteIsAnError) {
  test::TempDir dir;
  const fs::path csv = dir.path() / "hist.csv", gp = dir.path() / "plot.gp";
  std::ofstream(csv) << "someone's data\n";
  std::ofstream(gp) << "someone's script\n";
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"--histogram", csv.string()}, {"--plot", (dir.path() / "plot.png").string()}}) {
    std::vector<std::string> argv = args;
    argv.insert(argv.end(), {"--duration", "0.05"});
    const CliRun r = rt_check(argv, dir.path());
    EXPECT_EQ(r.exit_code, 1) << args[0] << ": " << r.out;
    EXPECT_NE(r.out.find("exists; give --overwrite to replace it"), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("verdict"), std::string::npos) << "refused before measuring: " << r.out;
  }
  EXPECT_EQ(contents(csv), "someone's data\n");
  EXPECT_EQ(contents(gp), "someone's script\n");
  EXPECT_FALSE(fs::exists(dir.path() / "plot.png"));
  // A symbolic link is no place to write to (a dangling one was refused only after measuring, or
  // written through), and one file named twice would be written twice (refused half-way).
  const fs::path link = dir.path() / "link.csv";
  fs::create_symlink(dir.path() / "nowhere" / "h.csv", link);
  const fs::path png = dir.path() / "h.png";
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"--histogram", link.string()}, {"--histogram", link.string(), "--overwrite"},
        {"--plot", png.string(), "--histogram", (dir.path() / "h.dat").string()},
        {"--plot", png.string(), "--histogram", png.string()}}) {
    std::vector<std::string> argv = args;
    argv.insert(argv.end(), {"--duration", "0.05"});
    const CliRun r = rt_check(argv, dir.path());
    EXPECT_EQ(r.exit_code, 1) << args[0] << " " << args[1] << ": " << r.out;
    EXPECT_TRUE(r.out.find("symbolic link") != std::string::npos || r.out.find("writes too") != std::string::npos)
        << r.out;
    EXPECT_EQ(r.out.find("verdict"), std::string::npos) << "refused before measuring: " << r.out;
  }
  EXPECT_FALSE(fs::exists(png));
  const CliRun replaced = rt_check({"--duration", "0.05", "--histogram", csv.string(), "--overwrite"}, dir.path());
  ASSERT_EQ(replaced.exit_code, 0) << replaced.out;
  EXPECT_EQ(contents(csv).rfind("# lftrack rt-check", 0), 0u) << contents(csv);
  if (!fs::exists("/dev/full")) GTEST_SKIP() << "no /dev/full on this host";
  const CliRun full = rt_check({"--duration", "0.05", "--histogram", "/dev/full"}, dir.path());
  EXPECT_EQ(full.exit_code, 1) << full.out;
  EXPECT_NE(full.out.find("/dev/full: write failed: No space left on device"), std::string::npos) << full.out;
}

// A report on standard output that cannot be written is a failure (issue 50 probe: `rt-check
// --json > /dev/full`, `journal export J > /dev/full` exited 0 with nothing written).
TEST(RtCheckCli, AReportStandardOutputCannotTakeIsAFailure) {
  if (!fs::exists("/dev/full")) GTEST_SKIP() << "no /dev/full on this host";
  test::TempDir dir;
  const std::string command = quoted(LFTRACK_BIN_PATH) + " -q rt-check --duration 0.05 --json >/dev/full 2>" +
                              quoted((dir.path() / "err.txt").string());
  const int status = std::system(command.c_str());
  ASSERT_TRUE(status != -1 && WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 1);
  EXPECT_NE(contents(dir.path() / "err.txt").find("cannot write standard output"), std::string::npos)
      << contents(dir.path() / "err.txt");
}

}  // namespace
}  // namespace lftrack::session
