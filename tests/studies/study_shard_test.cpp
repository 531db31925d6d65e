// Shards of studies for job arrays (issue 25): the task record and idempotent tasks, the trade
// and capture-range shard files, merging and pooling over patients, and the Slurm job array's
// scripts and submission (against a stand-in sbatch; the real cluster is in Cli.SlurmJobArray*).

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <iterator>
#include <sstream>

#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/studies/capture_range_study.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"  // run_process
#include "lftrack/tracking/thread_pool.hpp"
#include "small_phantom.hpp"
#include "lftrack/studies/slurm_job_array.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "lftrack/studies/trade_study.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::capture_range_shard_samples;
using studies::CaptureRangeOptions;
using studies::CaptureRangeReport;
using studies::CaptureRangeRun;
using studies::check_capture_range_shard_complete;
using studies::check_job_array_spec;
using studies::check_trade_shard_complete;
using studies::folder_safe_name;
using studies::job_array_scripts;
using studies::JobArraySpec;
using studies::JobScript;
using studies::merge_capture_range_shards;
using studies::merge_trade_shards;
using studies::parse_registration_method;
using studies::pool_capture_range_reports;
using studies::pool_trade_studies;
using studies::read_capture_range_shard;
using studies::read_shard_task;
using studies::read_trade_shard;
using studies::record_shard_task;
using studies::run_process;
using studies::run_shard_task;
using studies::shard_dir;
using studies::ShardPhase;
using studies::ShardTask;
using studies::study_scene_fingerprint;
using studies::submit_job_array;
using studies::tally_trade_verdict;
using studies::TradeResult;
using studies::TradeStudy;
using studies::write_capture_range_outputs;
using studies::write_capture_range_shard;
using studies::write_file_atomically;
using studies::write_trade_shard;

using loop::VerdictReason;
namespace {

namespace fs = std::filesystem;

std::string read_text(const fs::path& file) {
  std::ifstream in(file);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

TEST(StudyShard, ATaskRunsOnceAndAFinishedShardIsNotComputedAgain) {
  test::TempDir dir;
  const fs::path shard = dir.path() / "shard";
  int runs = 0;
  bool complete = false;
  auto check = [&]() -> Status { return complete ? Status{} : corrupt_data("torn"); };
  auto run = [&]() -> Status {
    ++runs;
    std::ofstream(shard / "study.json") << "{}";
    complete = true;
    return {};
  };
  ASSERT_TRUE(run_shard_task(shard, check, run).ok());
  EXPECT_EQ(runs, 1);
  EXPECT_EQ(read_shard_task(shard).phase, ShardPhase::kDone);
  std::string said;
  ASSERT_TRUE(run_shard_task(shard, check, run, &said).ok());
  EXPECT_EQ(runs, 1) << "a complete shard is not computed again";
  EXPECT_NE(said.find("nothing to do"), std::string::npos) << said;
  // A torn result is computed again; another study's result is refused, never overwritten.
  complete = false;
  ASSERT_TRUE(run_shard_task(shard, check, run, &said).ok());
  EXPECT_EQ(runs, 2);
  EXPECT_NE(said.find("incomplete (torn)"), std::string::npos) << said;
  const Status other = run_shard_task(
      shard, [] { return failed_precondition("holds another study"); }, run);
  EXPECT_EQ(other.code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(other.message().find("refusing to overwrite"), std::string::npos) << other.message();
  EXPECT_EQ(runs, 2);
}

TEST(StudyShard, AFailedTaskAndADeadTaskReadAsFailed) {
  test::TempDir dir;
  const fs::path shard = dir.path() / "s";
  EXPECT_EQ(read_shard_task(shard).phase, ShardPhase::kPending);
  const Status s = run_shard_task(
      shard, [] { return Status{}; }, [] { return io_error("disk full"); });
  EXPECT_FALSE(s.ok());
  ShardTask t = read_shard_task(shard);
  EXPECT_EQ(t.phase, ShardPhase::kFailed);
  EXPECT_EQ(t.message, "disk full");
  EXPECT_GT(t.finished_unix_s, 0);
  // A record of a running task whose process has gone (this host) is a failure, not "running".
  ASSERT_TRUE(record_shard_task(shard, ShardPhase::kRunning).ok());
  EXPECT_EQ(read_shard_task(shard).phase, ShardPhase::kRunning) << "this process is alive";
  std::string text = read_text(shard / "task.json");
  const std::string pid = "\"pid\": " + std::to_string(getpid());
  ASSERT_NE(text.find(pid), std::string::npos) << text;
  text.replace(text.find(pid), pid.size(), "\"pid\": 2147483000");
  std::ofstream(shard / "task.json") << text;
  t = read_shard_task(shard);
  EXPECT_EQ(t.phase, ShardPhase::kFailed);
  EXPECT_NE(t.message.find("gone"), std::string::npos) << t.message;
  std::ofstream(shard / "task.json") << "{ not json";
  EXPECT_EQ(read_shard_task(shard).phase, ShardPhase::kFailed);
  // A live task on this host (the test's parent process stands in for it) is not run twice.
  text.replace(text.find("\"pid\": 2147483000"), 17, "\"pid\": " + std::to_string(getppid()));
  std::ofstream(shard / "task.json") << text;
  int runs = 0;
  const Status second = run_shard_task(
      shard, [] { return corrupt_data("torn"); },
      [&] {
        ++runs;
        return Status{};
      });
  EXPECT_EQ(second.code(), StatusCode::kFailedPrecondition) << second.message();
  EXPECT_NE(second.message().find("another task"), std::string::npos) << second.message();
  EXPECT_EQ(runs, 0);
}

TEST(StudyShard, AtomicWritesLeaveNoPartialFiles) {
  test::TempDir dir;
  ASSERT_TRUE(write_file_atomically(dir.path() / "a.txt", "one").ok());
  ASSERT_TRUE(write_file_atomically(dir.path() / "a.txt", "two").ok());
  EXPECT_EQ(read_text(dir.path() / "a.txt"), "two");
  int files = 0;
  for (const auto& e : fs::directory_iterator(dir.path())) files += e.is_regular_file();
  EXPECT_EQ(files, 1);
  EXPECT_FALSE(write_file_atomically(dir.path() / "missing" / "a.txt", "x").ok());
}

TradeResult point(const std::string& id, std::vector<double> tre, std::vector<double> ms) {
  TradeResult r;
  r.point.id = id;
  r.point.lf_resolution = {4, 4, 48, 48};
  r.runs = int(tre.size());
  r.problem_tre_mm = std::move(tre);
  r.problem_ms = std::move(ms);
  r.mean_tre_mm = 1;
  r.memory_bytes = 1e6;
  // Judged by the verdict (a shard's result records it): a registration that ran was accepted.
  for (double t : r.problem_ms) {
    r.problem_accepted.push_back(!std::isnan(t));
    r.problem_verdict_reason.push_back(std::isnan(t) ? int(VerdictReason::kNoResult) : 0);
  }
  r.verdict = tally_trade_verdict(r, 2.0);
  return r;
}

TradeStudy study(const std::string& scene, std::vector<TradeResult> results, int shard = 1, int shards = 1) {
  TradeStudy s;
  s.scene = scene;
  s.seed = 7;
  s.problems = 2;
  s.quick = true;
  s.shard = shard;
  s.shards = shards;
  s.points_total = 3;
  s.results = std::move(results);
  return s;
}

TEST(TradeShards, AShardIsCompleteOnlyWithItsPointsAndEveryProblemRow) {
  test::TempDir dir;
  const TradeStudy s = study("p1", {point("a", {0.5, 3.0}, {10, 20}), point("c", {0.2, 0.4}, {5, NAN})}, 1, 2);
  ASSERT_TRUE(write_trade_shard(s, dir.path()).ok());
  auto back = read_trade_shard(dir.path());
  ASSERT_TRUE(back.ok()) << back.status().message();
  ASSERT_EQ(back->results.size(), 2u);
  EXPECT_EQ(back->results[1].problem_tre_mm, (std::vector<double>{0.2, 0.4}));
  EXPECT_TRUE(std::isnan(back->results[1].problem_ms[1])) << "a failed registration has no time";
  TradeStudy expected = s;
  expected.results.clear();
  EXPECT_TRUE(check_trade_shard_complete(dir.path(), expected, {"a", "c"}).ok());
  EXPECT_EQ(check_trade_shard_complete(dir.path(), expected, {"a", "b"}).code(), StatusCode::kCorruptData);
  TradeStudy other_seed = expected;
  other_seed.seed = 8;
  EXPECT_EQ(check_trade_shard_complete(dir.path(), other_seed, {"a", "c"}).code(), StatusCode::kFailedPrecondition);
  TradeStudy more_problems = expected;
  more_problems.problems = 3;
  EXPECT_FALSE(check_trade_shard_complete(dir.path(), more_problems, {"a", "c"}).ok());
  // A runs.csv cut short, or one with a row out of order, is not a result.
  std::string runs = read_text(dir.path() / "runs.csv");
  std::ofstream(dir.path() / "runs.csv") << runs.substr(0, runs.rfind('\n', runs.size() - 2) + 1);
  EXPECT_FALSE(check_trade_shard_complete(dir.path(), expected, {"a", "c"}).ok());
  std::ofstream(dir.path() / "runs.csv") << "id,problem,tre_mm,ms\na,1,0.5,10\n";
  EXPECT_EQ(read_trade_shard(dir.path()).status().code(), StatusCode::kCorruptData);
  std::ofstream(dir.path() / "runs.csv") << "id,problem,tre_mm,ms\na,0,-1,10\n";
  EXPECT_EQ(read_trade_shard(dir.path()).status().code(), StatusCode::kCorruptData);
  // Values that do not parse or cannot be, and a description out of range, are refused.
  ASSERT_TRUE(write_trade_shard(s, dir.path()).ok());
  const std::string points = read_text(dir.path() / "points.csv");
  const std::string row = points.substr(points.find("\na,") + 1);
  auto with_field = [&](int field, const std::string& value) {
    std::vector<std::string> cells;
    std::istringstream in(row.substr(0, row.find('\n')));
    for (std::string c; std::getline(in, c, ',');) cells.push_back(c);
    cells[std::size_t(field)] = value;
    std::string line;
    for (const auto& c : cells) line += (line.empty() ? "" : ",") + c;
    std::ofstream(dir.path() / "points.csv") << points.substr(0, points.find('\n') + 1) << line << "\n";
    return read_trade_shard(dir.path()).status();
  };
  EXPECT_EQ(with_field(15, "1e12").code(), StatusCode::kCorruptData) << "runs";
  EXPECT_EQ(with_field(20, "7").code(), StatusCode::kCorruptData) << "a success rate of 700 %";
  EXPECT_EQ(with_field(18, "nan").code(), StatusCode::kCorruptData) << "a mean TRE that is not a number";
  EXPECT_EQ(with_field(16, "abc").code(), StatusCode::kCorruptData) << "a time that does not parse";
  ASSERT_TRUE(write_trade_shard(s, dir.path()).ok());
  std::string description = read_text(dir.path() / "study.json");
  description.replace(description.find("\"shards\": 2"), 12, "\"shards\": 0");
  std::ofstream(dir.path() / "study.json") << description;
  EXPECT_EQ(read_trade_shard(dir.path()).status().code(), StatusCode::kCorruptData) << "shard 1 of 0";
}

TEST(TradeShards, MergingRestoresTheStudysOrder) {
  // Points 0, 2 in shard 1 and point 1 in shard 2.
  const auto merged = merge_trade_shards({study("p", {point("y", {1, 1}, {1, 1})}, 2, 2),
                                          study("p", {point("x", {1, 1}, {1, 1}), point("z", {1, 1}, {1, 1})}, 1, 2)});
  ASSERT_TRUE(merged.ok()) << merged.status().message();
  ASSERT_EQ(merged->results.size(), 3u);
  EXPECT_EQ(merged->results[0].point.id, "x");
  EXPECT_EQ(merged->results[1].point.id, "y");
  EXPECT_EQ(merged->results[2].point.id, "z");
}

TEST(TradeShards, PoolingRecomputesFromEveryPatientsProblems) {
  TradeStudy p1 = study("p1", {point("a", {0.5, 3.0}, {10, 20}), point("only-p1", {1, 1}, {1, 1})});
  TradeStudy p2 = study("p2", {point("a", {0.1, 0.3}, {30, NAN})});
  p2.results[0].memory_bytes = 3e6;
  std::vector<std::string> left_out;
  auto pooled = pool_trade_studies({p1, p2}, &left_out);
  ASSERT_TRUE(pooled.ok()) << pooled.status().message();
  ASSERT_EQ(pooled->results.size(), 1u);
  const TradeResult& a = pooled->results[0];
  EXPECT_EQ(a.runs, 4);
  EXPECT_EQ(pooled->problems, 4);
  EXPECT_NEAR(a.mean_tre_mm, (0.5 + 3.0 + 0.1 + 0.3) / 4, 1e-12);
  EXPECT_NEAR(a.success_rate, 0.5, 1e-12);             // 3.0 mm fails, and the registration that failed
  EXPECT_EQ(a.failed_runs, 1);                         // (issue 50: it counted by its start's TRE)
  EXPECT_NEAR(a.median_ms, 20, 1e-12);                 // of 10, 20, 30; the failed run has no time
  EXPECT_NEAR(a.memory_bytes, 2e6, 1e-6);              // averaged over the patients
  EXPECT_EQ(left_out, std::vector<std::string>{"only-p1"});
  EXPECT_NE(pooled->scene.find("p1 + p2"), std::string::npos);
  EXPECT_FALSE(pool_trade_studies({p1, p1}).ok()) << "a scene given twice";
  TradeStudy other = p2;
  other.seed = 99;
  EXPECT_FALSE(pool_trade_studies({p1, other}).ok()) << "another seed";
  TradeStudy no_rows = p2;
  no_rows.results[0].problem_tre_mm.clear();
  EXPECT_FALSE(pool_trade_studies({p1, no_rows}).ok()) << "a study without per-problem rows";
}

CaptureRangeReport capture_shard(const std::string& scene, int shard, int shards) {
  CaptureRangeReport r;
  r.scene = scene;
  r.options.methods = {*parse_registration_method("warm:ncc")};
  r.options.per_bin = 3;
  r.options.bins = 2;
  r.options.shard = shard;
  r.options.shards = shards;
  for (int k = shard - 1; k < 3; k += shards)
    for (int b = 0; b < 2; ++b) {
      CaptureRangeRun run;
      run.method = "warm:ncc";
      run.bin = b;
      run.sample = k;
      run.initial_tre_mm = 2 * b + 1;
      run.tre_mean_mm = b == 0 ? 0.3 : 2.2;
      run.tre_max_mm = run.tre_mean_mm + 0.1;
      run.success = run.tre_mean_mm < 2;
      run.success_loose = run.tre_mean_mm < 2.5;
      run.ms = 10 + k;
      r.runs.push_back(run);
    }
  return r;
}

TEST(CaptureRangeShards, ShardsRoundTripMergeAndPool) {
  test::TempDir dir;
  EXPECT_EQ(capture_range_shard_samples(capture_shard("p", 1, 2).options), 2);
  EXPECT_EQ(capture_range_shard_samples(capture_shard("p", 2, 2).options), 1);
  CaptureRangeOptions five = capture_shard("p", 4, 5).options;
  EXPECT_EQ(capture_range_shard_samples(five), 0) << "more shards than samples: shard 4 of 5 has none";
  std::vector<CaptureRangeReport> read;
  for (int k : {2, 1}) {
    const auto shard_dir = dir.path() / ("s" + std::to_string(k));
    const CaptureRangeReport s = capture_shard("p", k, 2);
    ASSERT_TRUE(write_capture_range_shard(s, shard_dir).ok());
    EXPECT_TRUE(check_capture_range_shard_complete(shard_dir, s).ok());
    CaptureRangeReport other = s;
    other.options.seed = 2;
    EXPECT_EQ(check_capture_range_shard_complete(shard_dir, other).code(), StatusCode::kFailedPrecondition);
    auto back = read_capture_range_shard(shard_dir);
    ASSERT_TRUE(back.ok()) << back.status().message();
    read.push_back(*back);
  }
  auto merged = merge_capture_range_shards(read);
  ASSERT_TRUE(merged.ok()) << merged.status().message();
  ASSERT_EQ(merged->runs.size(), 6u);
  for (std::size_t i = 0; i < merged->runs.size(); ++i) EXPECT_EQ(merged->runs[i].sample, int(i / 2));
  ASSERT_EQ(merged->summaries.size(), 1u);
  EXPECT_NEAR(merged->summaries[0].success_rate, 0.5, 1e-12);
  EXPECT_NEAR(merged->summaries[0].capture_range_mm, 2, 1e-12);
  EXPECT_FALSE(merge_capture_range_shards({read[0]}).ok()) << "shard 1 of 2 missing";
  EXPECT_FALSE(merge_capture_range_shards({read[0], read[0]}).ok()) << "a shard twice";
  CaptureRangeReport second = *merged;
  second.scene = "q";
  auto pooled = pool_capture_range_reports({*merged, second});
  ASSERT_TRUE(pooled.ok());
  EXPECT_EQ(pooled->runs.size(), 12u);
  EXPECT_EQ(pooled->options.per_bin, 6);
  EXPECT_FALSE(pool_capture_range_reports({*merged, *merged}).ok());
  // A row twice, or a sample of another shard, is not a shard's result.
  const fs::path s1 = dir.path() / "s1";
  const std::string runs = read_text(s1 / "runs.csv");
  const std::string first_row = runs.substr(runs.find('\n') + 1, runs.find('\n', runs.find('\n') + 1) - runs.find('\n'));
  std::string twice = runs;
  twice.replace(twice.rfind("warm:ncc"), std::string::npos, first_row);
  std::ofstream(s1 / "runs.csv") << twice;
  EXPECT_EQ(read_capture_range_shard(s1).status().code(), StatusCode::kCorruptData);
  std::string foreign = runs;
  const auto sample_at = foreign.find(",0,", foreign.find('\n') + 1);  // bin 0..2 mm: ",0,2,0,"
  foreign.replace(foreign.find(",2,0,", sample_at - 2), 5, ",2,1,");
  std::ofstream(s1 / "runs.csv") << foreign;
  EXPECT_EQ(read_capture_range_shard(s1).status().code(), StatusCode::kCorruptData) << "sample 1 is shard 2's";
  // Whole outputs: their description comes last, so a failed plot leaves no result behind.
  if (std::system("command -v gnuplot >/dev/null 2>&1") == 0) {
    const fs::path out = dir.path() / "out";
    fs::create_directories(out / "capture_range.png");  // gnuplot cannot write its image here
    EXPECT_FALSE(write_capture_range_outputs(*merged, out).ok());
    EXPECT_FALSE(fs::exists(out / "study.json"));
    fs::remove(out / "capture_range.png");
    EXPECT_TRUE(write_capture_range_outputs(*merged, out).ok());
    EXPECT_TRUE(fs::exists(out / "study.json"));
  }
  // A shard folder with a trade study in it is another study.
  ASSERT_TRUE(write_trade_shard(study("p", {}), dir.path() / "trade").ok());
  EXPECT_EQ(read_capture_range_shard(dir.path() / "trade").status().code(), StatusCode::kFailedPrecondition);
}

JobArraySpec spec_in(const fs::path& dir) {
  JobArraySpec s;
  s.study = "capture-range";
  s.scenes = {"/scenes/p one.yaml", "/scenes/it's.yaml"};
  s.scene_names = {"p_one", "its"};
  s.out_dir = dir / "study out";
  s.work_dir = dir;
  s.lftrack = (dir / "fake-lftrack").string();
  s.shards = 3;
  s.study_args = {"--per-bin", "4", "--methods", "warm:ncc"};
  return s;
}

TEST(SlurmJobArray, RefusesWhatCannotBeSubmitted) {
  test::TempDir dir;
  EXPECT_TRUE(check_job_array_spec(spec_in(dir.path())).ok());
  auto with = [&](auto edit) {
    JobArraySpec s = spec_in(dir.path());
    edit(s);
    return check_job_array_spec(s);
  };
  EXPECT_TRUE(with([](JobArraySpec& s) { s.study = "realism"; }).ok());
  EXPECT_NE(with([](JobArraySpec& s) { s.study = "sensitivity"; }).message().find("expected trade, capture-range or "
                                                                                  "realism"),
            std::string::npos);
  EXPECT_FALSE(with([](JobArraySpec& s) { s.scene_names = {"a", "a"}; }).ok());
  EXPECT_FALSE(with([](JobArraySpec& s) { s.scene_names = {"a", "../b"}; }).ok());
  EXPECT_FALSE(with([](JobArraySpec& s) { s.shards = 0; }).ok());
  EXPECT_FALSE(with([](JobArraySpec& s) { s.time_limit = "1h"; }).ok());
  EXPECT_TRUE(with([](JobArraySpec& s) { s.time_limit = "1-02:00:00"; }).ok());
  EXPECT_FALSE(with([](JobArraySpec& s) { s.partition = "a b"; }).ok());
  EXPECT_FALSE(with([](JobArraySpec& s) { s.study_args = {"--out=/elsewhere"}; }).ok());
  EXPECT_FALSE(with([](JobArraySpec& s) { s.study_args = {"--shard", "1/2"}; }).ok());
  EXPECT_FALSE(with([](JobArraySpec& s) { s.study_args = {"--help"}; }).ok()) << "every task would print help";
  EXPECT_FALSE(with([&](JobArraySpec& s) { s.out_dir = dir.path() / "a\ntouch /tmp/x\n#"; }).ok());
  EXPECT_FALSE(with([&](JobArraySpec& s) { s.out_dir = dir.path() / "e%j"; }).ok()) << "sbatch expands %j";
  EXPECT_FALSE(with([](JobArraySpec& s) { s.scenes[0] = "/a\nb.yaml"; }).ok());
  EXPECT_FALSE(with([](JobArraySpec& s) { s.shards = 501; }).ok()) << "1002 array tasks";
  EXPECT_TRUE(with([](JobArraySpec& s) { s.shards = 500; }).ok());
  EXPECT_EQ(folder_safe_name("builtin spine phantom"), "builtin_spine_phantom");
  EXPECT_EQ(folder_safe_name("../x"), "scene.._x");
  EXPECT_EQ(folder_safe_name(std::string(300, 'a')).size(), 100u);
}

// Runs a generated script as Slurm would (SLURM_ARRAY_TASK_ID set) with a stand-in lftrack that
// prints its arguments one per line.
std::vector<std::string> task_arguments(const JobScript& script, int task) {
  std::string out;
  const Status s = run_process({"bash", script.file.string()}, &out,
                               {"SLURM_ARRAY_TASK_ID=" + std::to_string(task), "SLURM_CPUS_PER_TASK=3"});
  EXPECT_TRUE(s.ok()) << out;
  std::vector<std::string> args;
  std::istringstream in(out);
  for (std::string line; std::getline(in, line);) args.push_back(line);
  return args;
}

TEST(SlurmJobArray, EachTaskRunsItsSceneAndShardWithPathsQuoted) {
  test::TempDir dir;
  const JobArraySpec spec = spec_in(dir.path());
  std::ofstream(spec.lftrack) << "#!/bin/bash\nfor a in \"$@\"; do echo \"$a\"; done\n";
  fs::permissions(spec.lftrack, fs::perms::owner_all);
  fs::create_directories(spec.out_dir / "slurm");
  const auto scripts = job_array_scripts(spec);
  ASSERT_EQ(scripts.size(), 3u);
  for (const JobScript& j : scripts) std::ofstream(j.file) << j.text;
  EXPECT_EQ(scripts[0].array_size, 2);
  EXPECT_EQ(scripts[1].array_size, 6);
  EXPECT_EQ(scripts[2].array_size, 0);
  // Task 4 of the shards: scene 2 (4 / 3 = 1), shard 2 of 3.
  const auto args = task_arguments(scripts[1], 4);
  const std::vector<std::string> want{"study",   "capture-range",
                                      "--scene", "/scenes/it's.yaml",
                                      "--threads", "3",
                                      "--shard", "2/3",
                                      "--out",   (spec.out_dir / "shards/its/shard-2-of-3").string(),
                                      "--lf-dir", (spec.out_dir / "fields/its").string(),
                                      "--fields-prebuilt", "--per-bin", "4", "--methods", "warm:ncc"};
  EXPECT_EQ(args, want);
  const auto fields = task_arguments(scripts[0], 0);
  ASSERT_GE(fields.size(), 8u);
  EXPECT_EQ(fields[3], "/scenes/p one.yaml");
  EXPECT_EQ(fields[6], "--build-fields");
  const auto merge = task_arguments(scripts[2], 0);
  ASSERT_EQ(merge.size(), 4u + 6u);
  EXPECT_EQ(merge[1], "merge");
  EXPECT_EQ(merge[3], (spec.out_dir / "merged").string());
  EXPECT_EQ(merge[4], shard_dir(spec.out_dir, "p_one", 1, 3).string());
  EXPECT_EQ(merge[9], shard_dir(spec.out_dir, "its", 3, 3).string());
  // Outside a job array the scripts refuse to guess a task.
  std::string out;
  EXPECT_FALSE(run_process({"bash", scripts[1].file.string()}, &out).ok());
}

TEST(SlurmJobArray, SubmitChainsTheJobsAndRefusesAnotherStudysFolder) {
  test::TempDir dir;
  JobArraySpec spec = spec_in(dir.path());
  // A stand-in sbatch on PATH: records its arguments, answers with a job id (and a warning).
  const fs::path bin = dir.path() / "bin";
  fs::create_directories(bin);
  std::ofstream(bin / "sbatch") << "#!/bin/bash\necho \"$*\" >> '" << (dir.path() / "sbatch.log").string()
                                << "'\nn=$(wc -l < '" << (dir.path() / "sbatch.log").string()
                                << "')\necho 'sbatch: warning: a warning' >&2\necho \"$((100 + n));cluster\"\n";
  fs::permissions(bin / "sbatch", fs::perms::owner_all);
  const std::string old_path = std::getenv("PATH");
  setenv("PATH", (bin.string() + ":" + old_path).c_str(), 1);
  auto jobs = submit_job_array(spec);
  ASSERT_TRUE(jobs.ok()) << jobs.status().message();
  EXPECT_EQ(jobs->fields, "101");
  EXPECT_EQ(jobs->shards, "102");
  EXPECT_EQ(jobs->merge, "103");
  const std::string log = read_text(dir.path() / "sbatch.log");
  EXPECT_NE(log.find("--array=0-5"), std::string::npos) << log;
  EXPECT_NE(log.find("--dependency=afterok:101 --kill-on-invalid-dep=yes"), std::string::npos) << log;
  EXPECT_NE(log.find("--dependency=afterok:102"), std::string::npos) << log;
  EXPECT_TRUE(fs::exists(spec.out_dir / "slurm" / "shards.sh"));
  // The same submission again is accepted (its tasks finish what is missing); another is refused.
  EXPECT_TRUE(submit_job_array(spec).ok());
  JobArraySpec other = spec;
  other.shards = 4;
  const auto refused = submit_job_array(other);
  EXPECT_EQ(refused.status().code(), StatusCode::kFailedPrecondition);
  const std::string record = read_text(spec.out_dir / "submit.json");
  EXPECT_NE(record.find("\"106\""), std::string::npos) << "the second submission is recorded: " << record;
  // An sbatch that refuses the shards job: reported with what it said, the fields job cancelled.
  const fs::path calls = dir.path() / "calls.log";
  std::ofstream(bin / "sbatch") << "#!/bin/bash\nif [[ \"$*\" == *shards.sh ]]; then echo 'sbatch: error: invalid array' "
                                   ">&2; exit 1; fi\necho 201\n";
  std::ofstream(bin / "scancel") << "#!/bin/bash\necho \"scancel $*\" >> '" << calls.string() << "'\n";
  fs::permissions(bin / "scancel", fs::perms::owner_all);
  const auto failed = submit_job_array(spec);
  ASSERT_FALSE(failed.ok());
  EXPECT_NE(failed.status().message().find("invalid array"), std::string::npos) << failed.status().message();
  EXPECT_EQ(read_text(calls), "scancel 201\n");
  // A record whose history is not a list is refused before anything is queued.
  std::string damaged = read_text(spec.out_dir / "submit.json");
  damaged.replace(damaged.find("\"submissions\": ["), 16, "\"submissions\": \"x\", \"old\": [");
  std::ofstream(spec.out_dir / "submit.json") << damaged;
  fs::remove(calls);
  const auto refused_record = submit_job_array(spec);
  setenv("PATH", old_path.c_str(), 1);
  EXPECT_EQ(refused_record.status().code(), StatusCode::kCorruptData) << refused_record.status().message();
}

// What judges a study's results is part of its identity: a shard made with other floors, another
// edge band or view check, or another tolerance for "right" is another study, never reused.
TEST(StudyShard, TheVerdictsSettingsArePartOfTheStudysIdentity) {
  tracking::ThreadPool pool(2);
  auto p = test::small_phantom(&pool);
  ASSERT_TRUE(p.ok()) << p.status().message();
  const std::string base = study_scene_fingerprint(*p);
  EXPECT_EQ(study_scene_fingerprint(*p), base);
  const auto differs = [&](const std::function<void(PreparedScene&)>& change) {
    PreparedScene q = *p;
    change(q);
    return study_scene_fingerprint(q) != base;
  };
  EXPECT_TRUE(differs([](PreparedScene& q) { q.scene.verdict_checks.envelope_edge_mm = 1.0; }));
  EXPECT_TRUE(differs([](PreparedScene& q) { q.scene.verdict_checks.max_view_shift_mm = 0; }));
  EXPECT_TRUE(differs([](PreparedScene& q) { q.scene.safety.beam_tolerance_mm = 1.0; }));
  EXPECT_TRUE(differs([](PreparedScene& q) {
    q.scene.min_similarity_given = true;
    q.scene.safety.min_similarity = 50;
  }));
  EXPECT_FALSE(differs([](PreparedScene& q) { q.scene.verdict_checks.view_check_every = 3; }))
      << "how often the loop runs the view check does not change a study's verdicts";
}

}  // namespace
}  // namespace lftrack::session
