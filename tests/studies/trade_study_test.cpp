// The trade study's pure parts: the Pareto front, the recommendations, shard files and merging,
// the summary; and the point list. The runs themselves are exercised by Cli.TradeStudy*.

#include "lftrack/studies/trade_study.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
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

}  // namespace
}  // namespace lftrack::host
