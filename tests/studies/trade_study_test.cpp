// The trade study's pure parts: the Pareto front, the recommendations, shard files and merging,
// the summary; and the point list. The runs themselves are exercised by Cli.TradeStudy*.

#include "lftrack/studies/trade_study.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <iterator>
#include <set>

#include "test_data.hpp"

namespace lftrack::host {
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

}  // namespace
}  // namespace lftrack::host
