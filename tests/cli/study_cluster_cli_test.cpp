// Sharded studies as a cluster runs them (issue 25): shards equal to the unsharded study, tasks
// that find their shard complete, light fields built once, and a real single-node Slurm cluster
// (scripts/slurm-local.sh) running `lftrack study submit`'s job array when the test runs as root.

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "cli_text.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"  // run_process
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;

namespace {

using test::lftrack_bin;

namespace fs = std::filesystem;

// The built-in phantom with a tiny 16-bit light field, named `name` (one "patient" per name).
fs::path patient_scene(const fs::path& dir, const std::string& name, int phantom_seed) {
  std::string scene = *builtin_scene_text(kBuiltinPhantom);
  auto swap = [&](const std::string& from, const std::string& to) {
    const auto at = scene.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    scene.replace(at, from.size(), to);
  };
  swap("    resolution: [16, 16, 128, 128]\n", "    resolution: [4, 4, 48, 48]\n    storage: fixed16\n");
  swap("name: builtin spine phantom", "name: " + name);
  swap("  seed: 1\n", "  seed: " + std::to_string(phantom_seed) + "\n");
  const fs::path file = dir / (name + ".yaml");
  std::ofstream(file) << scene;
  return file;
}

std::string read_text_file(const fs::path& file) {
  std::ifstream in(file);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A CSV's rows with only its first `columns` columns (the rest are times, which differ by run).
std::string columns_of(const fs::path& csv, int columns) {
  std::ifstream in(csv);
  std::string line, out;
  while (std::getline(in, line)) {
    std::istringstream cells(line);
    std::string cell;
    for (int c = 0; c < columns && std::getline(cells, cell, ','); ++c) out += cell + ",";
    out += "\n";
  }
  return out;
}

const std::vector<std::string> kCaptureArgs = {"--per-bin", "3", "--bins", "2", "--methods", "warm:ncc"};

std::vector<std::string> capture_range(const fs::path& scene, const std::vector<std::string>& more) {
  std::vector<std::string> a{lftrack_bin(), "-q", "study", "capture-range", "--scene", scene.string()};
  a.insert(a.end(), kCaptureArgs.begin(), kCaptureArgs.end());
  a.insert(a.end(), more.begin(), more.end());
  return a;
}

TEST(Cli, CaptureRangeShardsMergeIntoTheUnshardedStudyAndFinishedShardsAreNotRunAgain) {
  test::TempDir dir;
  const fs::path scene = patient_scene(dir.path(), "p1", 1);
  const std::string lf = (dir.path() / "lf").string();
  std::string out;
  // A task told the fields are prebuilt refuses to build them.
  EXPECT_FALSE(run_process(capture_range(scene, {"--out", (dir.path() / "x").string(), "--lf-dir", lf,
                                                 "--fields-prebuilt"}),
                           &out)
                   .ok());
  EXPECT_NE(out.find("the study's field job builds them"), std::string::npos) << out;
  ASSERT_TRUE(run_process(capture_range(scene, {"--build-fields", "--lf-dir", lf}), &out).ok()) << out;
  ASSERT_TRUE(run_process(capture_range(scene, {"--out", (dir.path() / "whole").string(), "--lf-dir", lf}), &out).ok())
      << out;
  std::vector<std::string> shards;
  for (const char* k : {"1/2", "2/2"}) {
    shards.push_back((dir.path() / (std::string("shard") += k[0])).string());
    ASSERT_TRUE(run_process(capture_range(scene, {"--shard", k, "--out", shards.back(), "--lf-dir", lf,
                                                  "--fields-prebuilt"}),
                            &out)
                    .ok())
        << out;
  }
  std::vector<std::string> merge{lftrack_bin(), "-q", "study", "merge", "--out", (dir.path() / "merged").string()};
  merge.insert(merge.end(), shards.rbegin(), shards.rend());
  ASSERT_TRUE(run_process(merge, &out).ok()) << out;
  const std::string whole = columns_of(dir.path() / "whole" / "runs.csv", 10);
  EXPECT_EQ(std::count(whole.begin(), whole.end(), '\n'), 1 + 3 * 2);
  EXPECT_EQ(columns_of(dir.path() / "merged" / "runs.csv", 10), whole) << "every run is the unsharded study's run";
  // Shard 1 again: found complete, not computed (its results keep their time).
  const auto written = fs::last_write_time(fs::path(shards[0]) / "runs.csv");
  ASSERT_TRUE(run_process(capture_range(scene, {"--shard", "1/2", "--out", shards[0], "--lf-dir", lf,
                                                "--fields-prebuilt"}),
                          &out)
                  .ok())
      << out;
  EXPECT_NE(out.find("nothing to do"), std::string::npos) << out;
  EXPECT_EQ(fs::last_write_time(fs::path(shards[0]) / "runs.csv"), written);
  // Another study in that folder (another seed) is refused, and the folder kept.
  EXPECT_FALSE(run_process(capture_range(scene, {"--shard", "1/2", "--seed", "5", "--out", shards[0]}), &out).ok());
  EXPECT_NE(out.find("refusing to overwrite"), std::string::npos) << out;
  EXPECT_EQ(fs::last_write_time(fs::path(shards[0]) / "runs.csv"), written);
  // The same name on another patient (another CT) is another study: refused, not taken as done.
  std::string other = read_text_file(scene);
  other.replace(other.find("  seed: 1\n"), 10, "  seed: 4\n");
  std::ofstream(dir.path() / "p1-other-ct.yaml") << other;
  EXPECT_FALSE(run_process(capture_range(dir.path() / "p1-other-ct.yaml", {"--shard", "1/2", "--out", shards[0]}), &out)
                   .ok());
  EXPECT_NE(out.find("fingerprint"), std::string::npos) << out;
  // A merge into one of its shards would overwrite it: refused.
  EXPECT_FALSE(run_process({lftrack_bin(), "study", "merge", "--out", shards[0], shards[0], shards[1]}, &out).ok());
  EXPECT_NE(out.find("is, or is inside, the shard folder"), std::string::npos) << out;
  EXPECT_EQ(fs::last_write_time(fs::path(shards[0]) / "runs.csv"), written);
  EXPECT_FALSE(run_process(capture_range(scene, {"--shard", "4294967297/4294967298", "--out", shards[0]}), &out).ok());
  // A torn shard (its description lost) is computed again.
  fs::remove(fs::path(shards[0]) / "study.json");
  ASSERT_TRUE(run_process(capture_range(scene, {"--shard", "1/2", "--out", shards[0], "--lf-dir", lf,
                                                "--fields-prebuilt"}),
                          &out)
                  .ok())
      << out;
  EXPECT_TRUE(fs::exists(fs::path(shards[0]) / "study.json"));
}

TEST(Cli, TradeStudyFieldsAreBuiltOnceAndShardsOnlyMapThem) {
  test::TempDir dir;
  const fs::path scene = patient_scene(dir.path(), "p1", 1);
  const std::string lf = (dir.path() / "fields").string();
  const std::vector<std::string> common{lftrack_bin(), "-q",         "study",  "trade",
                                        "--scene",     scene.string(), "--quick", "--problems",
                                        "1",           "--points",   "baseline,lf-st32,bin2"};
  auto with = [&](std::vector<std::string> more) {
    auto a = common;
    a.insert(a.end(), more.begin(), more.end());
    return a;
  };
  std::string out;
  EXPECT_FALSE(run_process(with({"--shard", "1/2", "--out", (dir.path() / "x").string(), "--lf-dir", lf,
                                 "--fields-prebuilt"}),
                           &out)
                   .ok());
  EXPECT_NE(out.find("are not built in"), std::string::npos) << out;
  ASSERT_TRUE(run_process(with({"--build-fields", "--lf-dir", lf}), &out).ok()) << out;
  int sets = 0;
  for (const auto& e : fs::directory_iterator(lf)) {
    ++sets;
    int fields = 0, records = 0;
    for (const auto& f : fs::directory_iterator(e.path())) {
      fields += f.path().extension() == ".lf";
      records += f.path().filename().string().rfind("build-", 0) == 0 && f.path().extension() == ".json";
    }
    EXPECT_EQ(fields, 2) << e.path();
    EXPECT_EQ(records, 1) << e.path();
  }
  EXPECT_EQ(sets, 2) << "baseline and bin2 share one field set, lf-st32 has its own";
  ASSERT_TRUE(run_process(with({"--out", (dir.path() / "whole").string()}), &out).ok()) << out;
  for (const char* k : {"1/2", "2/2"})
    ASSERT_TRUE(run_process(with({"--shard", k, "--out", (dir.path() / (std::string("s") += k[0])).string(),
                                  "--lf-dir", lf, "--fields-prebuilt"}),
                            &out)
                    .ok())
        << out;
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "study", "merge", "--out", (dir.path() / "merged").string(),
                           (dir.path() / "s1").string(), (dir.path() / "s2").string()},
                          &out)
                  .ok())
      << out;
  // Settings, runs and TRE columns (1-16, 19-21) agree; times and precompute differ by run.
  auto accuracy = [](const fs::path& csv) {
    std::string all = columns_of(csv, 21), kept;
    std::istringstream lines(all);
    for (std::string line; std::getline(lines, line);) {
      std::istringstream cells(line);
      std::string cell;
      for (int c = 1; std::getline(cells, cell, ','); ++c)
        if (c <= 16 || c >= 19) kept += cell + ",";
      kept += "\n";
    }
    return kept;
  };
  EXPECT_EQ(accuracy(dir.path() / "merged" / "points.csv"), accuracy(dir.path() / "whole" / "points.csv"));
  EXPECT_EQ(columns_of(dir.path() / "merged" / "runs.csv", 3), columns_of(dir.path() / "whole" / "runs.csv", 3));
}

// Issue 50: a point whose every registration fails (bin4: binning beyond the registration's 16)
// was on the Pareto front as "0.0 ms, 67 %" (no time, and the starts' TREs counted as
// successes). It is on no front and is reported failed, with the reason.
TEST(Cli, ATradePointWhoseRegistrationsFailIsReportedFailedAndOnNoFront) {
  test::TempDir dir;
  const fs::path scene = patient_scene(dir.path(), "p1", 1);
  std::string out;
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "study", "trade", "--scene", scene.string(), "--quick", "--problems",
                           "3", "--points", "baseline,bin4", "--out", (dir.path() / "out").string()},
                          &out)
                  .ok())
      << out;
  EXPECT_EQ(out.find("\nbin4 "), std::string::npos) << "on the front: " << out;
  EXPECT_NE(out.find("FAILED bin4"), std::string::npos) << out;
  EXPECT_NE(out.find("3 of 3 registrations failed: registration: a level needs a blur"), std::string::npos) << out;
  const std::string summary = read_text_file(dir.path() / "out" / "summary.md");
  EXPECT_EQ(summary.substr(0, summary.find("## Recommended defaults")).find("| bin4 |"), std::string::npos) << summary;
  EXPECT_NE(summary.find("| bin4 | failed | failed |"), std::string::npos) << summary;
  const std::string points = read_text_file(dir.path() / "out" / "points.csv");
  std::istringstream row(points.substr(points.find("\nbin4,") + 1));
  std::vector<std::string> cells;
  for (std::string cell; cells.size() < 31 && std::getline(row, cell, ',');) cells.push_back(cell);
  ASSERT_EQ(cells.size(), 31u) << points;
  EXPECT_EQ(cells[16], "nan") << "no median time";
  EXPECT_EQ(cells[20], "0") << "no success";
  EXPECT_EQ(cells[25], "3") << "failed runs";
  // The registration verdict: a failed registration is rejected (no result) and never right.
  EXPECT_EQ(cells[27] + cells[28] + cells[29] + cells[30].substr(0, 1), "0003") << points;
  const std::string runs = read_text_file(dir.path() / "out" / "runs.csv");
  int bin4_rows = 0;
  for (std::size_t at = runs.find("\nbin4,"); at != std::string::npos; at = runs.find("\nbin4,", at + 1)) {
    const std::string line = runs.substr(at + 1, runs.find('\n', at + 1) - at - 1);
    ++bin4_rows;
    EXPECT_EQ(line.substr(line.size() - 4), ",0,1") << "accepted 0, VerdictReason::kNoResult: " << line;
  }
  EXPECT_EQ(bin4_rows, 3) << runs;
  const std::size_t verdict_row = out.find("\n  bin4 ");
  ASSERT_NE(verdict_row, std::string::npos) << "the verdict's table names it: " << out;
  const std::string counts = out.substr(verdict_row + 7, out.find('\n', verdict_row + 1) - verdict_row - 7);
  EXPECT_EQ(counts.substr(counts.find_first_not_of(' ')), "0         0         0         3") << out;
}

// The trade study on clinical frames (issue 21): the physics is recorded and named in the summary,
// a folder of ideal frames is not overwritten by it, and a bad --physics is refused before work.
TEST(Cli, TradeStudyOnClinicalFramesRecordsItsPhysics) {
  test::TempDir dir;
  const fs::path scene = patient_scene(dir.path(), "p1", 1);
  const std::string out_dir = (dir.path() / "clinical").string();
  const std::vector<std::string> common{lftrack_bin(), "-q",      "study",      "trade", "--scene", scene.string(),
                                        "--quick",     "--problems", "1",        "--points", "bin2"};
  auto with = [&](std::vector<std::string> more) {
    auto a = common;
    a.insert(a.end(), more.begin(), more.end());
    return a;
  };
  std::string out;
  EXPECT_FALSE(run_process(with({"--physics", "bogus", "--out", out_dir}), &out).ok());
  EXPECT_NE(out.find("--physics"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(out_dir));
  ASSERT_TRUE(run_process(with({"--physics", "clinical", "--out", out_dir}), &out).ok()) << out;
  std::ifstream study(fs::path(out_dir) / "study.json");
  const std::string text((std::istreambuf_iterator<char>(study)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("\"physics\": \"clinical\""), std::string::npos) << text;
  std::ifstream summary(fs::path(out_dir) / "summary.md");
  const std::string md((std::istreambuf_iterator<char>(summary)), std::istreambuf_iterator<char>());
  EXPECT_NE(md.find("clinical physics"), std::string::npos) << md;
  EXPECT_FALSE(run_process(with({"--out", out_dir}), &out).ok());  // ideal frames: another study
  EXPECT_NE(out.find("another study"), std::string::npos) << out;
}

// A single-node Slurm cluster under a test folder, stopped when the test ends.
class LocalSlurm {
 public:
  explicit LocalSlurm(const fs::path& dir) : dir_(dir) {
    started_ = run_process({"bash", std::string(LFTRACK_SOURCE_DIR) + "/scripts/slurm-local.sh", "start", dir.string()},
                           &log_)
                   .ok();
  }
  ~LocalSlurm() {
    std::string ignored;
    (void)run_process({"bash", std::string(LFTRACK_SOURCE_DIR) + "/scripts/slurm-local.sh", "stop", dir_.string()},
                      &ignored);
  }
  bool started() const { return started_; }
  const std::string& log() const { return log_; }
  std::string conf() const { return "SLURM_CONF=" + (dir_ / "slurm.conf").string(); }

 private:
  fs::path dir_;
  bool started_ = false;
  std::string log_;
};

TEST(Cli, SlurmJobArrayOnALocalClusterEqualsTheUnshardedStudy) {
  if (geteuid() != 0) GTEST_SKIP() << "a local Slurm cluster needs root (slurmd starts jobs as their owner)";
  std::string out;
  for (const char* tool : {"slurmctld", "slurmd", "sbatch", "munged", "mungekey"})
    if (std::system((std::string("command -v ") + tool + " >/dev/null 2>&1").c_str()) != 0)
      GTEST_SKIP() << tool << " is not installed (scripts/setup.sh installs Slurm)";
  test::TempDir dir;
  LocalSlurm cluster(dir.path() / "slurm");
  // A host whose Slurm cannot start (a container without what slurmd needs) skips, saying why;
  // LFTRACK_REQUIRE_SLURM=1 makes that a failure.
  if (!cluster.started()) {
    const char* require = std::getenv("LFTRACK_REQUIRE_SLURM");
    ASSERT_FALSE(require && std::string(require) == "1") << cluster.log();
    GTEST_SKIP() << "the local Slurm cluster did not start: " << cluster.log();
  }
  const fs::path p1 = patient_scene(dir.path(), "patient-1", 1);
  const fs::path p2 = patient_scene(dir.path(), "patient-2", 2);
  const fs::path study = dir.path() / "study";
  std::vector<std::string> submit{lftrack_bin(), "study", "submit", "--scheduler", "slurm", "--study", "capture-range",
                                  "--scene", p1.string(), "--scene", p2.string(), "--out", study.string(),
                                  "--shards", "2", "--cpus-per-task", "1", "--"};
  submit.insert(submit.end(), kCaptureArgs.begin(), kCaptureArgs.end());
  ASSERT_TRUE(run_process(submit, &out, {cluster.conf()}).ok()) << out;
  EXPECT_NE(out.find("submitted: fields job"), std::string::npos) << out;
  // Wait for the merge (the whole array is about 7 processes of a few seconds each).
  nlohmann::json status;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::minutes(3);
  while (std::chrono::steady_clock::now() < deadline) {
    ASSERT_TRUE(run_process({lftrack_bin(), "study", "status", study.string(), "--json"}, &out).ok()) << out;
    status = nlohmann::json::parse(out.substr(out.find('{')));
    if (status["merged"].get<bool>() || status["failed"].get<int>() > 0) break;
    std::this_thread::sleep_for(std::chrono::seconds(1));
  }
  ASSERT_TRUE(status["merged"].get<bool>()) << status.dump(2) << "\nlogs in " << (study / "slurm" / "logs");
  EXPECT_EQ(status["done"].get<int>(), 4);
  for (const auto& row : status["shards"]) EXPECT_FALSE(row["slurm_job"].get<std::string>().empty()) << row;
  // Each patient's merged study equals the same study run unsharded, outside Slurm; the pooled
  // study holds both patients' runs.
  for (const auto& [scene, name] : {std::pair{p1, "patient-1"}, std::pair{p2, "patient-2"}}) {
    const fs::path whole = dir.path() / (std::string(name) + "-whole");
    ASSERT_TRUE(run_process(capture_range(scene, {"--out", whole.string(), "--lf-dir", (dir.path() / "lf" / name).string()}),
                            &out)
                    .ok())
        << out;
    EXPECT_EQ(columns_of(study / "merged" / name / "runs.csv", 10), columns_of(whole / "runs.csv", 10)) << name;
  }
  const std::string pooled = columns_of(study / "merged" / "pooled" / "runs.csv", 1);
  EXPECT_EQ(std::count(pooled.begin(), pooled.end(), '\n'), 1 + 2 * 3 * 2);
  // The same submission again: every task finds its shard complete.
  ASSERT_TRUE(run_process(submit, &out, {cluster.conf()}).ok()) << out;
  std::ifstream record(study / "submit.json");
  EXPECT_EQ(nlohmann::json::parse(record)["submissions"].size(), 2u);
}

// The realism study (issue 21) on the tiny phantom: one gold pose, the ideal and the clinical
// sets. Every set's capture-range study and the summary's factors are written; physics that
// differs from the planning CT costs accuracy.
TEST(Cli, RealismStudyReportsEachFactorSet) {
  test::TempDir dir;
  const fs::path scene = patient_scene(dir.path(), "p1", 1);
  const fs::path out = dir.path() / "realism";
  std::string said;
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "study", "realism", "--scene", scene.string(), "--gold-poses", "2",
                           "--anatomy-draws", "1", "--only", "ideal,spectrum,clinical", "--lf-dir",
                           (dir.path() / "lf").string(), "--out", out.string()},
                          &said)
                  .ok())
      << said;
  const auto summary = nlohmann::json::parse(read_text_file(out / "summary.json"));
  ASSERT_EQ(summary["factors"].size(), 3u);
  EXPECT_EQ(summary["factors"][0]["name"], "ideal");
  EXPECT_EQ(summary["factors"][2]["name"], "clinical");
  for (const auto& f : summary["factors"]) {
    EXPECT_TRUE(fs::exists(out / f["name"].get<std::string>() / "runs.csv")) << f["name"];
    for (const char* key : {"mean_tre_mm", "success_rate", "median_ms"}) EXPECT_TRUE(f.contains(key)) << key;
    EXPECT_EQ(f["runs"], 2 * 5);  // 2 gold poses x the 5 bins up to 10 mm
  }
  EXPECT_NE(summary["factors"][2]["physics"].get<std::string>().find("scatter"), std::string::npos);
  EXPECT_GT(summary["factors"][0]["success_rate"].get<double>(), 0.5);
  EXPECT_GT(summary["factors"][2]["mean_tre_mm"].get<double>(), summary["factors"][0]["mean_tre_mm"].get<double>());
  const auto study = nlohmann::json::parse(read_text_file(out / "clinical" / "study.json"));
  EXPECT_EQ(study["options"]["physics"], "clinical");
  EXPECT_TRUE(fs::exists(out / "realism.csv"));
  // Unknown factor sets are refused, with the known ones, even beside a known one.
  EXPECT_FALSE(run_process({lftrack_bin(), "-q", "study", "realism", "--scene", scene.string(), "--only",
                            "ideal,bogus", "--lf-dir", (dir.path() / "lf").string(), "--out",
                            (dir.path() / "x").string()},
                           &said)
                   .ok());
  EXPECT_NE(said.find("'bogus', not a factor set of this scene (ideal, "), std::string::npos) << said;
  // A second study into the same folder is refused and the first one's summary stays.
  const std::string before = read_text_file(out / "summary.json");
  EXPECT_FALSE(run_process({lftrack_bin(), "-q", "study", "realism", "--scene", scene.string(), "--only", "ideal",
                            "--seed", "7", "--lf-dir", (dir.path() / "lf").string(), "--out", out.string()},
                           &said)
                   .ok());
  EXPECT_NE(said.find("holds a realism study already"), std::string::npos) << said;
  EXPECT_EQ(read_text_file(out / "summary.json"), before);
}

// A realism study in shards (issue 25): the field job builds the light fields once, each shard
// task maps them, the merge equals the unsharded study set by set, a finished shard is not run
// again, and `study submit --study realism` writes tasks that run exactly these commands.
TEST(Cli, RealismShardsMergeIntoTheUnshardedStudy) {
  test::TempDir dir;
  const fs::path scene = patient_scene(dir.path(), "p1", 1);
  const std::string lf = (dir.path() / "lf").string();
  auto realism = [&](std::vector<std::string> more) {
    std::vector<std::string> a{lftrack_bin(), "-q",      "study", "realism", "--scene", scene.string(), "--gold-poses",
                               "2",           "--bins",  "3",     "--anatomy-draws", "1", "--only", "ideal,clinical",
                               "--lf-dir",    lf};
    a.insert(a.end(), more.begin(), more.end());
    return a;
  };
  std::string out;
  EXPECT_FALSE(run_process(realism({"--shard", "1/2", "--out", (dir.path() / "x").string(), "--fields-prebuilt"}), &out)
                   .ok());
  EXPECT_NE(out.find("the study's field job builds them"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(dir.path() / "x" / "study.json"));
  ASSERT_TRUE(run_process(realism({"--build-fields"}), &out).ok()) << out;
  const fs::path whole = dir.path() / "whole";
  ASSERT_TRUE(run_process(realism({"--out", whole.string()}), &out).ok()) << out;
  std::vector<std::string> shards;
  for (const char* k : {"1/2", "2/2"}) {
    shards.push_back((dir.path() / (std::string("shard") += k[0])).string());
    ASSERT_TRUE(run_process(realism({"--shard", k, "--out", shards.back(), "--fields-prebuilt"}), &out).ok()) << out;
    EXPECT_TRUE(fs::exists(fs::path(shards.back()) / "study.json"));
    EXPECT_FALSE(fs::exists(fs::path(shards.back()) / "summary.json")) << "a shard is not a whole study";
  }
  // A merge missing a shard is refused; the whole merge (shards in any order) is the whole study.
  EXPECT_FALSE(run_process({lftrack_bin(), "-q", "study", "merge", "--out", (dir.path() / "half").string(), shards[0]},
                           &out)
                   .ok());
  const fs::path merged = dir.path() / "merged";
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "study", "merge", "--out", merged.string(), shards[1], shards[0]}, &out)
                  .ok())
      << out;
  EXPECT_NE(out.find("clinical"), std::string::npos) << "the merge prints the realism table: " << out;
  for (const char* set : {"ideal", "clinical"}) {
    const std::string runs = columns_of(whole / set / "runs.csv", 10);
    EXPECT_EQ(std::count(runs.begin(), runs.end(), '\n'), 1 + 2 * 3) << set << ": 2 gold poses x 3 bins to 6 mm";
    EXPECT_EQ(columns_of(merged / set / "runs.csv", 10), runs) << set << ": every run is the unsharded study's run";
  }
  const auto summary_whole = nlohmann::json::parse(read_text_file(whole / "summary.json"));
  const auto summary_merged = nlohmann::json::parse(read_text_file(merged / "summary.json"));
  ASSERT_EQ(summary_merged["factors"].size(), 2u);
  for (std::size_t i = 0; i < 2; ++i) {
    for (const char* key : {"name", "runs", "success_rate"})
      EXPECT_EQ(summary_merged["factors"][i][key], summary_whole["factors"][i][key]) << i << " " << key;
    // The merge reads the runs back from runs.csv (10 significant digits).
    for (const char* key : {"mean_tre_mm", "p95_tre_mm"})
      EXPECT_NEAR(summary_merged["factors"][i][key].get<double>(), summary_whole["factors"][i][key].get<double>(), 1e-8)
          << i << " " << key;
  }
  EXPECT_EQ(summary_merged["fingerprint"], summary_whole["fingerprint"]);
  EXPECT_TRUE(fs::exists(merged / "realism.csv"));
  // Shard 1 again: found complete, not computed; another seed in its folder is refused.
  const auto written = fs::last_write_time(fs::path(shards[0]) / "clinical" / "runs.csv");
  ASSERT_TRUE(run_process(realism({"--shard", "1/2", "--out", shards[0], "--fields-prebuilt"}), &out).ok()) << out;
  EXPECT_NE(out.find("nothing to do"), std::string::npos) << out;
  EXPECT_FALSE(run_process(realism({"--shard", "1/2", "--seed", "9", "--out", shards[0], "--fields-prebuilt"}), &out)
                   .ok());
  EXPECT_EQ(fs::last_write_time(fs::path(shards[0]) / "clinical" / "runs.csv"), written);
  // A shard whose set folder was lost reads as incomplete, and the merge says which.
  fs::remove_all(fs::path(shards[1]) / "clinical");
  EXPECT_FALSE(run_process({lftrack_bin(), "-q", "study", "merge", "--out", (dir.path() / "m2").string(), shards[0],
                            shards[1]},
                           &out)
                   .ok());
  EXPECT_NE(out.find("clinical"), std::string::npos) << out;
  // The job array runs these commands.
  ASSERT_TRUE(run_process({lftrack_bin(), "study", "submit", "--scheduler", "slurm", "--study", "realism", "--scene",
                           scene.string(), "--out", (dir.path() / "array").string(), "--shards", "2", "--dry-run",
                           "--", "--gold-poses", "2", "--only", "ideal,clinical"},
                          &out)
                  .ok())
      << out;
  EXPECT_NE(out.find("study realism --scene \"${scenes[$i]}\""), std::string::npos) << out;
  EXPECT_NE(out.find("--build-fields"), std::string::npos) << out;
  EXPECT_NE(out.find("--fields-prebuilt"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(dir.path() / "array")) << "a dry run writes nothing";
  // Options the realism study does not take are refused before anything is submitted.
  EXPECT_FALSE(run_process({lftrack_bin(), "study", "submit", "--scheduler", "slurm", "--study", "realism", "--scene",
                            scene.string(), "--out", (dir.path() / "array").string(), "--shards", "2", "--dry-run",
                            "--", "--points", "bin2"},
                           &out)
                   .ok());
}

}  // namespace
}  // namespace lftrack::session
