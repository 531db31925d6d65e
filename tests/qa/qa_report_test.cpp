// The daily QA's report (issue 59): JSON and HTML side by side, never replacing an earlier
// report, and found again by `lftrack run` only when it passed, today, for the same room.

#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/qa/qa_report.hpp"
#include "test_data.hpp"

namespace lftrack::qa {
namespace {

namespace fs = std::filesystem;

DailyQaReport a_report(bool passed, const std::string& room = "00112233445566778899aabbccddeeff") {
  DailyQaReport r;
  r.scene_name = "QA phantom <b>";  // escaped in the page
  r.scene_source = "/etc/lftrack/qa-phantom.yaml";
  r.room_fingerprint = room;
  r.started_utc = "2026-11-30T06:30:00Z";
  r.date_utc = "2026-11-30";
  r.tolerance_mm = 0.5;
  r.tolerance_deg = 0.2;
  OffsetResult o;
  o.shift(0) = 10;
  o.registered(0) = 10.04;
  o.registration_error_mm = 0.04;
  o.couch_error_mm = passed ? 0.1 : 3.0;
  o.aligned = true;
  o.passed = passed;
  o.why = passed ? "" : "the couch moved ...";
  r.offsets.push_back(o);
  QaCheck c;
  c.name = "offset";
  c.passed = passed;
  c.why = o.why;
  r.checks.push_back(c);
  r.not_checked = {"detector image quality"};
  return r;
}

TEST(QaReport, IsWrittenAsJsonAndHtmlBesideEarlierReportsNeverOverThem) {
  test::TempDir dir;
  auto first = write_daily_qa_report(a_report(true), dir.path() / "qa");
  ASSERT_TRUE(first.ok()) << first.status().message();
  auto second = write_daily_qa_report(a_report(true), dir.path() / "qa");  // the same second
  ASSERT_TRUE(second.ok()) << second.status().message();
  EXPECT_NE(first->json, second->json);
  EXPECT_EQ(first->json.filename(), "qa-daily-20261130-063000.json");
  EXPECT_EQ(second->json.filename(), "qa-daily-20261130-063000-2.json");
  std::ifstream in(first->json);
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["passed"], true);
  EXPECT_EQ(j["date_utc"], "2026-11-30");
  EXPECT_DOUBLE_EQ(j["offsets"][0]["registration_error_mm"].get<double>(), 0.04);
  const std::string html = test::contents(first->html);
  EXPECT_NE(html.find("PASSED"), std::string::npos);
  EXPECT_NE(html.find("<svg"), std::string::npos) << "the offset test's picture";
  EXPECT_NE(html.find("QA phantom &lt;b&gt;"), std::string::npos) << "names are escaped";
  EXPECT_EQ(html.find("QA phantom <b>"), std::string::npos);
}

TEST(QaReport, RunFindsOnlyAPassedReportOfItsRoomFromToday) {
  test::TempDir dir;
  const fs::path qa = dir.path() / "qa";
  const std::string room = "00112233445566778899aabbccddeeff";
  EXPECT_FALSE(passed_daily_qa(qa, room, "2026-11-30")) << "no folder: nothing";
  ASSERT_TRUE(write_daily_qa_report(a_report(false), qa).ok());
  EXPECT_FALSE(passed_daily_qa(qa, room, "2026-11-30")) << "a failed QA does not count";
  ASSERT_TRUE(write_daily_qa_report(a_report(true, "ffffffffffffffffffffffffffffffff"), qa).ok());
  EXPECT_FALSE(passed_daily_qa(qa, room, "2026-11-30")) << "another room's QA does not count";
  std::ofstream(qa / "qa-daily-garbage.json") << "{ not json";
  std::ofstream(qa / "qa-daily-array.json") << "[1, 2]";
  auto good = write_daily_qa_report(a_report(true), qa);
  ASSERT_TRUE(good.ok());
  const auto found = passed_daily_qa(qa, room, "2026-11-30");
  ASSERT_TRUE(found.has_value());
  EXPECT_EQ(*found, good->json);
  EXPECT_FALSE(passed_daily_qa(qa, room, "2026-12-01")) << "yesterday's QA does not count today";
  EXPECT_EQ(today_utc().size(), 10u);
}

}  // namespace
}  // namespace lftrack::qa
