// The daily QA's report (issue 59): JSON and HTML side by side, never replacing an earlier
// report, and found again by `lftrack run` only when it passed, today, for the same room.

#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/qa/qa_report.hpp"
#include "lftrack/session/scene_fingerprint.hpp"
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
  r.started_local = "2026-11-30T07:30:00+0100";
  r.date = "2026-11-30";
  r.standard = true;
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
  r.not_checked = {"a check not run"};
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
  EXPECT_EQ(j["date"], "2026-11-30");
  EXPECT_EQ(j["standard"], true);
  EXPECT_DOUBLE_EQ(j["offsets"][0]["registration_error_mm"].get<double>(), 0.04);
  const std::string html = test::contents(first->html);
  EXPECT_NE(html.find("PASSED"), std::string::npos);
  EXPECT_NE(html.find("<svg"), std::string::npos) << "the offset test's picture";
  EXPECT_NE(html.find("QA phantom &lt;b&gt;"), std::string::npos) << "names are escaped";
  EXPECT_EQ(html.find("QA phantom <b>"), std::string::npos);
}

TEST(QaReport, RunCountsTheNewestStandardReportOfItsRoomFromToday) {
  test::TempDir dir;
  const fs::path qa = dir.path() / "qa";
  const std::string room = "00112233445566778899aabbccddeeff";
  auto status = [&](const std::string& date = "2026-11-30") { return daily_qa_status(qa, room, date); };
  EXPECT_FALSE(status().passed) << "no folder: nothing";
  EXPECT_NE(status().detail.find("none of this room today"), std::string::npos) << status().detail;
  ASSERT_TRUE(write_daily_qa_report(a_report(false), qa).ok());
  EXPECT_FALSE(status().passed) << "a failed QA does not count";
  DailyQaReport other = a_report(true, "ffffffffffffffffffffffffffffffff");
  other.started_utc = "2026-11-30T06:40:00Z";
  ASSERT_TRUE(write_daily_qa_report(other, qa).ok());
  EXPECT_FALSE(status().passed) << "another room's QA does not count";
  // Files that are no report of ours are skipped, not fatal: garbage, wrong types, a folder, a link.
  std::ofstream(qa / "qa-daily-garbage.json") << "{ not json";
  std::ofstream(qa / "qa-daily-array.json") << "[1, 2]";
  std::ofstream(qa / "qa-daily-types.json") << R"({"kind": 1, "passed": "yes", "date": 20261130})";
  fs::create_directories(qa / "qa-daily-folder.json");
  DailyQaReport good_report = a_report(true);
  good_report.started_utc = "2026-11-30T06:50:00Z";
  auto good = write_daily_qa_report(good_report, qa);
  ASSERT_TRUE(good.ok());
  fs::create_symlink(good->json, qa / "qa-daily-link.json");
  EXPECT_TRUE(status().passed) << status().detail;
  EXPECT_EQ(status().file, good->json);
  EXPECT_FALSE(status("2026-12-01").passed) << "yesterday's QA does not count today";
  // A pass with looser settings than the standard QA does not count.
  DailyQaReport loose = a_report(true);
  loose.started_utc = "2026-11-30T07:00:00Z";
  loose.standard = false;
  ASSERT_TRUE(write_daily_qa_report(loose, qa).ok());
  EXPECT_FALSE(status().passed);
  EXPECT_NE(status().detail.find("looser settings"), std::string::npos) << status().detail;
  // The newest QA decides: a pass, then a failed re-run, is a failed day.
  DailyQaReport again = a_report(true);
  again.started_utc = "2026-11-30T08:00:00Z";
  ASSERT_TRUE(write_daily_qa_report(again, qa).ok());
  EXPECT_TRUE(status().passed) << status().detail;
  DailyQaReport failed = a_report(false);
  failed.started_utc = "2026-11-30T09:00:00Z";
  ASSERT_TRUE(write_daily_qa_report(failed, qa).ok());
  EXPECT_FALSE(status().passed) << "a newer failed QA overrides an earlier pass";
  EXPECT_NE(status().detail.find("newest QA of the room today failed"), std::string::npos) << status().detail;
}

// The room a daily QA counts for: its calibrations by contents (a detector recalibrated since the
// QA is another detector), not the patient's motion; a calibration that cannot be read gives
// another room, not an error.
TEST(RoomFingerprint, FollowsTheCalibrationsContentsNotThePatient) {
  test::TempDir dir;
  auto scene = session::load_scene((fs::path(LFTRACK_SOURCE_DIR) / "scenes" / "qa-phantom.yaml").string());
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  const auto plain = session::room_fingerprint(*scene);
  session::Scene moved = *scene;
  moved.motion.setup_error(0) = 9;
  EXPECT_EQ(session::room_fingerprint(moved), plain) << "another patient's set-up, the same room";

  const fs::path file = dir.path() / "detector-A.tif";
  auto write = [&](const std::string& bytes) {
    std::ofstream(file, std::ios::binary | std::ios::trunc) << bytes;
  };
  write("calibration of Monday");
  session::Scene calibrated = *scene;
  calibrated.detectors[0].calibration_file = file.string();
  const auto monday = session::room_fingerprint(calibrated);
  EXPECT_NE(monday, plain);
  EXPECT_EQ(session::room_fingerprint(calibrated), monday) << "the same file, the same room";
  write("calibration of Tuesday");
  const auto tuesday = session::room_fingerprint(calibrated);
  EXPECT_NE(tuesday, monday) << "the same name, other contents: recalibrated";
  write("calibration of Monday");
  EXPECT_EQ(session::room_fingerprint(calibrated), monday);

  fs::remove(file);
  const auto missing = session::room_fingerprint(calibrated);
  EXPECT_NE(missing, monday);
  EXPECT_NE(missing, (std::array<std::uint8_t, 16>{}));
}

}  // namespace
}  // namespace lftrack::qa
