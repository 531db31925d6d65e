// The trade study's pure parts: the Pareto front, the recommendations, shard files and merging,
// the summary; and the point list. The runs themselves are exercised by Cli.TradeStudy*; one small
// run here (TradeStudyRun) checks the registration verdict judges every result.

#include "lftrack/studies/trade_study.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <set>

#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "small_phantom.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::check_trade_shard_complete;
using studies::merge_trade_shards;
using studies::pareto_front;
using studies::pool_trade_studies;
using studies::read_trade_shard;
using studies::recommend;
using studies::run_trade_study;
using studies::tally_trade_verdict;
using studies::TradeOptions;
using studies::TradeRecommendations;
using studies::TradeResult;
using studies::TradeStudy;
using studies::VerdictOutcomes;
using studies::write_trade_outputs;
using studies::write_trade_shard;

using loop::VerdictReason;
namespace {

TradeResult result(const std::string& id, double ms, double tre, double memory_mb, double success = 1.0) {
  TradeResult r;
  r.point.id = id;
  r.point.lf_resolution = {16, 16, 128, 128};
  r.runs = 4;
  r.median_ms = ms;
  r.p95_ms = 1.5 * ms;
  r.mean_tre_mm = tre;
  r.p95_tre_mm = 2 * tre;
  r.success_rate = success;
  r.memory_bytes = memory_mb * 1e6;
  r.precompute_s = 3;
  r.ncc_vs_siddon = 0.999;
  r.psnr_db_vs_siddon = 40 + tre;
  return r;
}

std::vector<TradeResult> sample() {
  return {result("fast-rough", 10, 1.5, 4), result("flaky", 15, 0.8, 1, 0.9),
          result("middle", 30, 0.4, 40),    result("tie-a", 30, 0.4, 30),
          result("dominated", 40, 0.9, 2),  result("slow-exact", 5000, 0.2, 100),
          result("failing", 1, 9.0, 1, 0.0)};
}

std::set<std::string> ids(const std::vector<TradeResult>& v) {
  std::set<std::string> s;
  for (const auto& r : v) s.insert(r.point.id);
  return s;
}

TEST(TradeStudy, ParetoFrontKeepsEveryUndominatedPointSortedByTime) {
  const auto front = pareto_front(sample());
  EXPECT_EQ(ids(front), (std::set<std::string>{"fast-rough", "flaky", "middle", "tie-a", "slow-exact"}));
  for (std::size_t i = 1; i < front.size(); ++i) EXPECT_LE(front[i - 1].median_ms, front[i].median_ms);
  EXPECT_TRUE(pareto_front({}).empty());
}

TEST(TradeStudy, RecommendationsAreTheBestUnderEachConditionAndNeedReliability) {
  const TradeRecommendations r = recommend(sample());
  ASSERT_TRUE(r.has_fastest && r.has_accurate && r.has_least_memory);
  EXPECT_EQ(r.fastest_within_1mm.point.id, "middle");  // "flaky" is faster but succeeds 90 % of the time
  EXPECT_EQ(r.most_accurate_within_100ms.point.id, "middle");
  EXPECT_EQ(r.least_memory_within_half_mm.point.id, "tie-a");
  const TradeRecommendations none = recommend({result("rough", 5, 3.0, 1)});
  EXPECT_FALSE(none.has_fastest || none.has_least_memory);
}

TradeStudy shard_of(int k, int n, std::vector<TradeResult> results, int total) {
  TradeStudy s;
  s.scene = "test scene";
  s.seed = 4;
  s.problems = 4;
  s.shard = k;
  s.shards = n;
  s.points_total = total;
  s.results = std::move(results);
  return s;
}

TEST(TradeStudy, ShardsRoundTripThroughTheirFilesAndMerge) {
  test::TempDir dir;
  auto all = sample();
  const TradeStudy a = shard_of(1, 2, {all[0], all[1], all[2]}, 5);
  const TradeStudy b = shard_of(2, 2, {all[3], all[4]}, 5);
  ASSERT_TRUE(write_trade_shard(a, dir.path() / "a").ok());
  ASSERT_TRUE(write_trade_shard(b, dir.path() / "b").ok());
  auto ra = read_trade_shard(dir.path() / "a");
  auto rb = read_trade_shard(dir.path() / "b");
  ASSERT_TRUE(ra.ok()) << ra.status().message();
  ASSERT_TRUE(rb.ok());
  ASSERT_EQ(ra->results.size(), 3u);
  EXPECT_EQ(ra->results[2].point.id, "middle");
  EXPECT_DOUBLE_EQ(ra->results[2].mean_tre_mm, 0.4);
  EXPECT_DOUBLE_EQ(ra->results[1].success_rate, 0.9);
  EXPECT_EQ(ra->results[1].point.lf_resolution, (std::array<int, 4>{16, 16, 128, 128}));
  auto merged = merge_trade_shards({*rb, *ra});
  ASSERT_TRUE(merged.ok()) << merged.status().message();
  EXPECT_EQ(merged->results.size(), 5u);
  EXPECT_EQ(merged->shards, 1);

  auto refused = [](const Result<TradeStudy>& r, const std::string& words) {
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find(words), std::string::npos) << r.status().message();
  };
  refused(merge_trade_shards({*ra}), "shard 2 of 2 is missing");
  refused(merge_trade_shards({*ra, *ra}), "given twice");
  TradeStudy other = *rb;
  other.seed = 5;
  refused(merge_trade_shards({*ra, other}), "another study");
  // A shard whose frames carried other physics (issue 21) is another study; the name survives the
  // round trip, and a folder from before physics was recorded reads as ideal.
  EXPECT_EQ(ra->physics, "ideal");
  TradeStudy clinical = b;
  clinical.physics = "clinical";
  clinical.physics_description = "spectrum 120 kVp";
  ASSERT_TRUE(write_trade_shard(clinical, dir.path() / "clinical").ok());
  auto rc = read_trade_shard(dir.path() / "clinical");
  ASSERT_TRUE(rc.ok()) << rc.status().message();
  EXPECT_EQ(rc->physics, "clinical");
  EXPECT_EQ(rc->physics_description, "spectrum 120 kVp");
  refused(merge_trade_shards({*ra, *rc}), "another study");
  TradeStudy twice = *rb;
  twice.results[0].point.id = "middle";
  refused(merge_trade_shards({*ra, twice}), "measured twice");
  TradeStudy short_shard = *rb;
  short_shard.results.pop_back();
  refused(merge_trade_shards({*ra, short_shard}), "4 points, the study has 5");
  refused(merge_trade_shards({}), "no shards");
}

TEST(TradeStudy, DamagedShardFilesAreRefusedWithTheirLine) {
  test::TempDir dir;
  ASSERT_TRUE(write_trade_shard(shard_of(1, 1, sample(), 7), dir.path()).ok());
  {
    std::ofstream csv(dir.path() / "points.csv", std::ios::app);
    csv << "broken,lightfield,float\n";
  }
  auto r = read_trade_shard(dir.path());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("points.csv:9"), std::string::npos) << r.status().message();
  EXPECT_FALSE(read_trade_shard(dir.path() / "nowhere").ok());
  std::ofstream(dir.path() / "study.json") << "{ not json";
  EXPECT_FALSE(read_trade_shard(dir.path()).ok());
}

TEST(TradeStudy, OutputsNameTheFrontAndTheRecommendations) {
  test::TempDir dir;
  ASSERT_TRUE(write_trade_outputs(shard_of(1, 1, sample(), 7), dir.path()).ok());
  std::ifstream md(dir.path() / "summary.md");
  const std::string text((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("## Pareto front"), std::string::npos);
  EXPECT_NE(text.find("**fastest within 1 mm mean TRE**: `middle`"), std::string::npos) << text;
  EXPECT_NE(text.find("**least memory within 0.5 mm mean TRE**: `tie-a`"), std::string::npos);
  EXPECT_TRUE(std::filesystem::exists(dir.path() / "tre_vs_time.gp"));
  EXPECT_TRUE(std::filesystem::exists(dir.path() / "tre_vs_time_front.dat"));
  if (std::system("command -v gnuplot >/dev/null 2>&1") == 0) {
    EXPECT_GT(std::filesystem::file_size(dir.path() / "tre_vs_time.png"), 1000u);
    EXPECT_GT(std::filesystem::file_size(dir.path() / "memory_vs_fidelity.png"), 1000u);
  }
}

std::string text_of(const std::filesystem::path& file) {
  std::ifstream in(file);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A point whose registrations failed (issue 50: `bin4`, "a level needs a blur of 0 to 1000 mm
// ...") was on the front as "0.0 ms, 67 %": no time (so 0) and the starts' TREs counted as
// successes. A folder written then: its failed runs are the NaN times of runs.csv.
TEST(TradeStudy, AFailedPointInAnEarlierFolderIsOnNoFront) {
  test::TempDir dir;
  std::ofstream(dir.path() / "study.json")
      << R"({"study": "trade", "scene": "p", "seed": 1, "problems": 6, "quick": true, "shard": 1, "shards": 1,)"
      << R"( "points_total": 2})";
  const std::string settings = ",lightfield,float,0,16,16,128,128,1,0,";
  std::ofstream(dir.path() / "points.csv")
      << "id,renderer,storage,vq_codebook,lf_u,lf_v,lf_s,lf_t,envelope_scale,octree_pivot,bin,similarity,plan,"
         "final_step_mm,budget_ms,runs,median_ms,p95_ms,mean_tre_mm,p95_tre_mm,success_rate,memory_bytes,"
         "precompute_s,ncc_vs_siddon,psnr_db_vs_siddon\n"
      << "baseline" << settings << "1,mi,warm,0.1,0,6,20,25,0.4,0.6,1,8000000,3,0.999,40\n"
      << "bin4" << settings << "4,mi,warm,0.1,0,6,0,0,1.95,3.5,0.666666667,8000000,3,0.999,40\n";
  std::ofstream runs(dir.path() / "runs.csv");
  runs << "id,problem,tre_mm,ms\n";
  for (int k = 0; k < 6; ++k) runs << "baseline," << k << ",0.4,20\n";
  const double starts[6] = {1.5, 1.2, 1.9, 1.1, 3.5, 2.5};  // 4 under 2 mm
  for (int k = 0; k < 6; ++k) runs << "bin4," << k << "," << starts[k] << ",nan\n";
  runs.close();
  auto study = read_trade_shard(dir.path());
  ASSERT_TRUE(study.ok()) << study.status().message();
  EXPECT_EQ(ids(pareto_front(study->results)), (std::set<std::string>{"baseline"}));
  ASSERT_TRUE(write_trade_outputs(*study, dir.path() / "out").ok());
  const std::string md = text_of(dir.path() / "out" / "summary.md");
  EXPECT_EQ(md.find("| bin4 | 0.0"), std::string::npos) << md;
  EXPECT_NE(md.find("- `bin4`: 6 of 6 registrations failed: (reason not recorded)"), std::string::npos) << md;
}

TEST(TradeStudy, AFailedPointIsOnNoFrontAndIsShownFailedWithItsReason) {
  const std::string why =
      "registration: a level needs a blur of 0 to 1000 mm, a binning of 1 to 16 and a high-pass of 0 to 1000 mm";
  TradeResult bin4 = result("bin4", std::nan(""), 2.1, 4, 0.0);
  bin4.p95_ms = std::nan("");
  bin4.failed_runs = 4;
  bin4.failure = why;
  // Faster and more accurate than every point, but one of its registrations failed.
  TradeResult partly = result("partly-failed", 5, 0.1, 1, 0.75);
  partly.failed_runs = 1;
  partly.failure = why;
  auto results = sample();
  results.push_back(bin4);
  results.push_back(partly);
  EXPECT_EQ(ids(pareto_front(results)), ids(pareto_front(sample()))) << "no failed point on it, none beaten by one";
  const TradeRecommendations r = recommend(results);
  EXPECT_EQ(r.fastest_within_1mm.point.id, "middle");
  EXPECT_EQ(r.least_memory_within_half_mm.point.id, "tie-a");

  // The failure survives the shard's files (its commas are not cells) and merging.
  test::TempDir dir;
  ASSERT_TRUE(write_trade_shard(shard_of(1, 1, results, 9), dir.path() / "shard").ok());
  auto read = read_trade_shard(dir.path() / "shard");
  ASSERT_TRUE(read.ok()) << read.status().message();
  EXPECT_EQ(read->results[7].failed_runs, 4);
  EXPECT_TRUE(std::isnan(read->results[7].median_ms));
  EXPECT_NE(read->results[7].failure.find("a level needs a blur of 0 to 1000 mm; a binning"), std::string::npos)
      << read->results[7].failure;
  EXPECT_EQ(read->results[8].failed_runs, 1);
  EXPECT_EQ(read->results[0].failed_runs, 0);

  ASSERT_TRUE(write_trade_outputs(*read, dir.path() / "out").ok());
  const std::string md = text_of(dir.path() / "out" / "summary.md");
  const std::string front = md.substr(0, md.find("## Recommended defaults"));
  EXPECT_EQ(front.find("| bin4 |"), std::string::npos) << front;
  EXPECT_EQ(front.find("| partly-failed |"), std::string::npos) << front;
  EXPECT_NE(md.find("- `bin4`: 4 of 4 registrations failed: registration: a level needs a blur"), std::string::npos)
      << md;
  EXPECT_NE(md.find("| bin4 | failed | failed | failed | failed | failed | 4.00 |"), std::string::npos) << md;
  EXPECT_NE(md.find("**FAILED**, 1 of 4 registrations failed"), std::string::npos) << md;
}


// A point's verdict rows: whether each result was accepted, against whether it was right.
TradeResult judged_result(const std::string& id, std::vector<double> tre, std::vector<double> ms,
                          std::vector<int> accepted) {
  TradeResult r = result(id, 20, 0.5, 4);
  r.runs = int(tre.size());
  r.problem_tre_mm = std::move(tre);
  r.problem_ms = std::move(ms);
  r.problem_accepted = accepted;
  for (int a : accepted) r.problem_verdict_reason.push_back(a ? 0 : int(VerdictReason::kLowSimilarity));
  for (double m : r.problem_ms) r.failed_runs += std::isnan(m);
  return r;
}

TEST(TradeStudy, TheVerdictTallyCountsFourOutcomesAndAFailedRegistrationIsNeverRight) {
  const double nan = std::nan("");
  //                 right, accepted | wrong, accepted | right, rejected | wrong, rejected | failed (start 1.5 mm)
  const TradeResult r =
      judged_result("p", {0.4, 3.0, 0.5, 2.5, 1.5}, {10, 10, 10, 10, nan}, {1, 1, 0, 0, 0});
  const VerdictOutcomes v = tally_trade_verdict(r, 2.0);
  EXPECT_EQ(v.accepted_right, 1);
  EXPECT_EQ(v.accepted_wrong, 1);
  EXPECT_EQ(v.rejected_right, 1);
  EXPECT_EQ(v.rejected_wrong, 2) << "a failed registration under the tolerance is not right";
  EXPECT_EQ(v.total(), r.runs);
  // The tolerance decides what is right: at 3.5 mm the accepted 3 mm result is right.
  EXPECT_EQ(tally_trade_verdict(r, 3.5).accepted_right, 2);
  EXPECT_FALSE(tally_trade_verdict(result("unjudged", 10, 0.4, 1), 2.0).total()) << "no rows, nothing counted";
}

TEST(TradeStudy, TheVerdictSurvivesTheFilesMergingAndPooling) {
  const double nan = std::nan("");
  TradeResult a = judged_result("baseline", {0.4, 3.0, 0.5, 1.0}, {10, 12, 11, nan}, {1, 1, 0, 0});
  a.verdict = tally_trade_verdict(a, 2.0);
  TradeResult b = judged_result("bin2", {0.3, 0.3, 0.3, 0.3}, {5, 5, 5, 5}, {1, 1, 1, 1});
  b.verdict = tally_trade_verdict(b, 2.0);
  test::TempDir dir;
  ASSERT_TRUE(write_trade_shard(shard_of(1, 1, {a, b}, 2), dir.path() / "s").ok());
  auto read = read_trade_shard(dir.path() / "s");
  ASSERT_TRUE(read.ok()) << read.status().message();
  ASSERT_EQ(read->results.size(), 2u);
  EXPECT_EQ(read->results[0].verdict, a.verdict);
  EXPECT_EQ(read->results[0].problem_accepted, a.problem_accepted);
  EXPECT_EQ(read->results[0].problem_verdict_reason, a.problem_verdict_reason);
  EXPECT_EQ(read->verdict_tolerance_mm, 2.0);
  const std::string runs = text_of(dir.path() / "s" / "runs.csv");
  EXPECT_EQ(runs.substr(0, runs.find('\n')), "id,problem,tre_mm,ms,accepted,verdict_reason");
  EXPECT_NE(runs.find("baseline,2,0.5,11,0," + std::to_string(int(VerdictReason::kLowSimilarity))), std::string::npos)
      << runs;

  // Two scenes pooled: each scene's rows against its own tolerance, counted together.
  TradeStudy other = *read;
  other.scene = "another scene";
  other.verdict_tolerance_mm = 3.5;  // the accepted 3 mm result is right there
  auto pooled = pool_trade_studies({*read, other});
  ASSERT_TRUE(pooled.ok()) << pooled.status().message();
  const TradeResult& p = pooled->results[0];
  EXPECT_EQ(p.verdict.total(), 8);
  EXPECT_EQ(p.verdict.accepted_right, 1 + 2);
  EXPECT_EQ(p.verdict.accepted_wrong, 1 + 0);
  EXPECT_EQ(p.problem_accepted.size(), 8u);
  EXPECT_EQ(pooled->verdict_tolerance_mm, 0) << "scenes of different tolerances: each its own";

  // The outputs: summary.json and summary.md give the four outcomes, verdict.gp draws them.
  ASSERT_TRUE(write_trade_outputs(*read, dir.path() / "out").ok());
  std::ifstream summary_file(dir.path() / "out" / "summary.json");
  const auto summary = nlohmann::json::parse(summary_file);
  ASSERT_EQ(summary["points"].size(), 2u);
  EXPECT_EQ(summary["points"][0]["verdict"]["accepted_right"], 1);
  EXPECT_EQ(summary["points"][0]["verdict"]["false_accepts"], 1);
  EXPECT_EQ(summary["points"][0]["verdict"]["false_rejects"], 1);
  EXPECT_EQ(summary["points"][0]["verdict"]["rejected_wrong"], 1);
  EXPECT_EQ(summary["verdict_tolerance_mm"], 2.0);
  const std::string md = text_of(dir.path() / "out" / "summary.md");
  EXPECT_NE(md.find("## The registration verdict"), std::string::npos) << md;
  EXPECT_NE(md.find("| baseline | 4 | 1 | 1 | 1 | 1 |"), std::string::npos) << md;
  const std::string dat = text_of(dir.path() / "out" / "verdict.dat");
  EXPECT_NE(dat.find("baseline (n=4)"), std::string::npos) << dat;
  EXPECT_NE(dat.find("rejected, right (false reject)"), std::string::npos) << dat;
  if (std::system("command -v gnuplot >/dev/null 2>&1") == 0) {
    EXPECT_GT(std::filesystem::file_size(dir.path() / "out" / "verdict.png"), 1000u);
  }
}

// A folder written before the verdict reads as not judged (and is no complete shard: its task
// computes it again); its counts are refused when they do not add up to the runs.
TEST(TradeStudy, AFolderWithoutTheVerdictReadsAsNotJudged) {
  test::TempDir dir;
  std::ofstream(dir.path() / "study.json")
      << R"({"study": "trade", "scene": "p", "seed": 1, "problems": 2, "quick": true, "shard": 1, "shards": 1,)"
      << R"( "points_total": 1})";
  const std::string header =
      "id,renderer,storage,vq_codebook,lf_u,lf_v,lf_s,lf_t,envelope_scale,octree_pivot,bin,similarity,plan,"
      "final_step_mm,budget_ms,runs,median_ms,p95_ms,mean_tre_mm,p95_tre_mm,success_rate,memory_bytes,"
      "precompute_s,ncc_vs_siddon,psnr_db_vs_siddon,failed_runs,failure";
  const std::string row =
      "baseline,lightfield,float,0,16,16,128,128,1,0,1,mi,warm,0.1,0,2,20,25,0.4,0.6,1,8000000,3,0.999,40,0,";
  std::ofstream(dir.path() / "points.csv") << header << "\n" << row << "\n";
  std::ofstream(dir.path() / "runs.csv") << "id,problem,tre_mm,ms\nbaseline,0,0.4,20\nbaseline,1,0.4,20\n";
  auto old = read_trade_shard(dir.path());
  ASSERT_TRUE(old.ok()) << old.status().message();
  EXPECT_FALSE(old->results[0].judged());
  EXPECT_TRUE(old->results[0].problem_accepted.empty());
  TradeStudy expected = *old;
  const Status incomplete = check_trade_shard_complete(dir.path(), expected, {"baseline"});
  EXPECT_EQ(incomplete.code(), StatusCode::kCorruptData) << incomplete.message();
  EXPECT_NE(incomplete.message().find("no registration verdict"), std::string::npos) << incomplete.message();

  std::ofstream(dir.path() / "points.csv") << header << ",accepted_right,false_accepts,false_rejects,rejected_wrong\n"
                                           << row << ",1,0,0,0\n";
  auto short_counts = read_trade_shard(dir.path());
  ASSERT_FALSE(short_counts.ok());
  EXPECT_NE(short_counts.status().message().find("count 1 of 2 runs"), std::string::npos)
      << short_counts.status().message();
}

// Every result of a trade point is judged by the scene's verdict: with a floor no registration can
// reach (mutual information of 50), every one is rejected for its similarity, right or wrong, and
// the four outcomes add up to the runs.
TEST(TradeStudyRun, EveryResultIsJudgedByTheScenesVerdict) {
  tracking::ThreadPool pool(2);
  TradeOptions o;
  o.quick = true;
  o.problems = 2;
  o.only = {"baseline"};
  for (const double floor : {0.0, 50.0}) {
    auto p = test::small_phantom(&pool, floor);
    ASSERT_TRUE(p.ok()) << p.status().message();
    auto study = run_trade_study(*p, o, &pool);
    ASSERT_TRUE(study.ok()) << study.status().message();
    ASSERT_EQ(study->results.size(), 1u);
    const TradeResult& r = study->results[0];
    EXPECT_EQ(study->verdict_tolerance_mm, p->scene.safety.beam_tolerance_mm);
    EXPECT_TRUE(r.judged());
    EXPECT_EQ(r.verdict.total(), r.runs) << "floor " << floor;
    ASSERT_EQ(r.problem_accepted.size(), 2u);
    int right = 0;
    for (std::size_t k = 0; k < r.problem_tre_mm.size(); ++k)
      right += !std::isnan(r.problem_ms[k]) && r.problem_tre_mm[k] < study->verdict_tolerance_mm;
    EXPECT_EQ(r.verdict.accepted_right + r.verdict.rejected_right, right) << "floor " << floor;
    std::printf("floor %g: accepted right %d, false accepts %d, false rejects %d, rejected wrong %d (TRE %.3f mm)\n",
                floor, r.verdict.accepted_right, r.verdict.accepted_wrong, r.verdict.rejected_right,
                r.verdict.rejected_wrong, r.mean_tre_mm);
    if (floor > 0) {
      EXPECT_EQ(r.verdict.accepted_right + r.verdict.accepted_wrong, 0) << "a floor of 50 accepts nothing";
      for (int reason : r.problem_verdict_reason) EXPECT_EQ(reason, int(VerdictReason::kLowSimilarity));
    }
  }
}

}  // namespace
}  // namespace lftrack::session
