// The calibration-sensitivity study's registration verdict (geometry_sensitivity.hpp): every
// case's results are judged by the scene's verdict and counted in four outcomes that add up to
// the case's runs; its files carry them. The study's TRE figures are checked by
// ClosedLoop.SensitivityStudy* (slow).

#include "lftrack/studies/geometry_sensitivity.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>

#include "lftrack/tracking/thread_pool.hpp"
#include "small_phantom.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_geometry_sensitivity;
using studies::SensitivityCase;
using studies::SensitivityOptions;
using studies::write_sensitivity_outputs;

using loop::VerdictReason;
namespace {

std::string file_text(const std::filesystem::path& file) {
  std::ifstream in(file);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A floor no registration reaches (mutual information of 50): the verdict rejects every result of
// every case for its similarity, right or wrong; with the measure's default floor the outcomes
// still add up to the runs, and a right result is one under the scene's tolerance.
TEST(SensitivityStudy, EveryResultIsJudgedByTheScenesVerdict) {
  tracking::ThreadPool pool(2);
  SensitivityOptions o;
  o.runs = 1;
  for (const double floor : {0.0, 50.0}) {
    auto p = test::small_phantom(&pool, floor);
    ASSERT_TRUE(p.ok()) << p.status().message();
    auto report = run_geometry_sensitivity(*p, o, &pool);
    ASSERT_TRUE(report.ok()) << report.status().message();
    EXPECT_EQ(report->verdict_tolerance_mm, p->scene.safety.beam_tolerance_mm);
    EXPECT_EQ(report->measure, "mi");
    ASSERT_GE(report->cases.size(), 5u);
    for (const SensitivityCase& c : report->cases) {
      EXPECT_EQ(c.verdict.total(), o.runs) << c.key;
      ASSERT_EQ(c.run_accepted.size(), std::size_t(o.runs)) << c.key;
      const bool right = c.run_tre_mm[0] < report->verdict_tolerance_mm;
      EXPECT_EQ(c.verdict.accepted_right + c.verdict.rejected_right, int(right)) << c.key;
      EXPECT_EQ(c.verdict.accepted_right + c.verdict.accepted_wrong, c.run_accepted[0]) << c.key;
      std::printf("floor %g, %-18s TRE %.3f mm: %s (reason %d)\n", floor, c.key.c_str(), c.run_tre_mm[0],
                  c.run_accepted[0] ? "accepted" : "rejected", c.run_verdict_reason[0]);
      if (floor > 0) {
        EXPECT_EQ(c.run_accepted[0], 0) << c.key << ": a floor of 50 accepts nothing";
        EXPECT_EQ(c.run_verdict_reason[0], int(VerdictReason::kLowSimilarity)) << c.key;
      }
    }
    if (floor == 0) continue;
    // The files: runs.csv with the verdict's columns, summary.json with its counts, the chart.
    lftrack::test::TempDir dir;
    ASSERT_TRUE(write_sensitivity_outputs(*report, dir.path()).ok());
    const std::string runs = file_text(dir.path() / "runs.csv");
    EXPECT_EQ(runs.substr(0, runs.find('\n')), "case,run,tre_mm,added_mm,accepted,verdict_reason");
    EXPECT_EQ(std::count(runs.begin(), runs.end(), '\n'), long(1 + report->cases.size()));
    EXPECT_NE(runs.find("no-error,0,"), std::string::npos) << runs;
    std::ifstream summary_file(dir.path() / "summary.json");
    const auto summary = nlohmann::json::parse(summary_file);
    ASSERT_EQ(summary["cases"].size(), report->cases.size());
    for (const auto& c : summary["cases"]) {
      EXPECT_EQ(c["verdict"]["accepted_right"].get<int>() + c["verdict"]["false_accepts"].get<int>(), 0);
      EXPECT_EQ(c["verdict"]["false_rejects"].get<int>() + c["verdict"]["rejected_wrong"].get<int>(), o.runs);
    }
    const std::string dat = file_text(dir.path() / "verdict.dat");
    EXPECT_NE(dat.find("no-error (n=1)"), std::string::npos) << dat;
    EXPECT_NE(dat.find("accepted, wrong (false accept)"), std::string::npos) << dat;
    if (std::system("command -v gnuplot >/dev/null 2>&1") == 0) {
      EXPECT_GT(std::filesystem::file_size(dir.path() / "verdict.png"), 1000u);
    }
  }
}

}  // namespace
}  // namespace lftrack::session
