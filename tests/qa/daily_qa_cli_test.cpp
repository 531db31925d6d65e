// `lftrack qa daily` as a physicist runs it (issue 59): on the shipped QA phantom it passes, the
// latency chain and the control socket included (the real clock), writes its dated report, and
// the room's loop (`sim --room` on the simulated QA room, as `run` on a real one) then finds
// today's QA of the room; absurd values are refused before anything is loaded.

#include <gtest/gtest.h>

#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <optional>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>

#include "child_process.hpp"
#include "qa_phantom_support.hpp"

namespace lftrack::test {
namespace {

namespace fs = std::filesystem;

TEST(DailyQaCli, RefusesAbsurdValuesBeforeLoadingAnything) {
  TempDir dir;
  for (const char* bad :
       {"--tolerance-mm 0", "--tolerance-mm -1", "--tolerance-mm nan", "--tolerance-mm inf",
        "--tolerance-mm 1e12", "--tolerance-deg 0", "--latency-ms -5", "--latency-ms nan"}) {
    const CliRun r = shell(
        quoted(LFTRACK_BIN_PATH) + " qa daily --scene " + quoted(qa_phantom_scene().string()) + " " + bad,
        dir.path());
    EXPECT_EQ(r.exit_code, 1) << bad << ": " << r.out;
    EXPECT_NE(r.out.find("must be"), std::string::npos) << bad << ": " << r.out;
    EXPECT_EQ(r.out.find("CT builtin:phantom"), std::string::npos) << bad << ": loaded the CT first";
  }
  EXPECT_FALSE(fs::exists(dir.path() / "out" / "qa")) << "a refused QA wrote a report";
  const CliRun missing = shell(quoted(LFTRACK_BIN_PATH) + " qa daily --scene no-such-room.yaml", dir.path());
  EXPECT_EQ(missing.exit_code, 1) << missing.out;
}

TEST(DailyQaCli, PassesOnTheShippedRoomWritesItsReportAndTheLoopFindsIt) {
  TempDir dir;
  const fs::path fields = qa_phantom_fields(LFTRACK_BIN_PATH, qa_phantom_scene(), dir.path());
  ASSERT_FALSE(fields.empty()) << contents(dir.path() / "precompute.txt");
  const std::string scene = quoted(qa_phantom_scene().string());
  const std::string lf = " --lf-dir " + quoted(fields.string());
  const CliRun before = shell(
      quoted(LFTRACK_BIN_PATH) + " -q " + qa_phantom_loop() + " --check --rt ignore --scene " + scene + lf,
      dir.path(), "before.txt");
  EXPECT_NE(before.out.find("[warn] daily QA: none of this room today"), std::string::npos) << before.out;

  // The latency chain runs on the real clock with the scene's real-time set-up (enforce): root
  // here, or the limits the unit grants.
  if (::geteuid() != 0)
    GTEST_SKIP() << "the QA's latency chain needs the real-time grants (root or the unit's limits)";
  // A host starved by its neighbours can overrun a cycle (the latency check's reason); then the
  // QA is run again, twice at most. Any other failure is the test's.
  CliRun qa;
  for (int attempt = 0; attempt < 3; ++attempt) {
    qa = shell(quoted(LFTRACK_BIN_PATH) + " qa daily --scene " + scene + lf, dir.path(), "qa.txt");
    const bool starved =
        qa.exit_code == 1 && qa.out.find("latency: FAIL") != std::string::npos &&
        qa.out.find("offset: FAIL") == std::string::npos && qa.out.find("beam: FAIL") == std::string::npos &&
        (qa.out.find("overran") != std::string::npos || qa.out.find("p99") != std::string::npos);
    if (!starved) break;
    std::cout << "starved host, the QA again: " << qa.out << "\n";
  }
  ASSERT_EQ(qa.exit_code, 0) << qa.out;
  for (const char* line : {"detector A: pass", "detector B: pass", "beam: pass", "latency: pass",
                           "daily QA PASSED: out/qa/qa-daily-"})
    EXPECT_NE(qa.out.find(line), std::string::npos) << line << " missing:\n" << qa.out;
  EXPECT_NE(qa.out.find("not checked: a drift of the detectors"), std::string::npos) << qa.out;
  EXPECT_NE(qa.out.find("real-time set-up: memory locked, SCHED_FIFO, pinned"), std::string::npos) << qa.out;
  int reports = 0;
  for (const auto& e : fs::directory_iterator(dir.path() / "out" / "qa"))
    reports += e.path().extension() == ".json" || e.path().extension() == ".html";
  EXPECT_GE(reports, 2);

  // The room's start-up checks now see it (any scene of the same detectors and actuator would).
  const CliRun after = shell(
      quoted(LFTRACK_BIN_PATH) + " -q " + qa_phantom_loop() + " --check --rt ignore --scene " + scene + lf,
      dir.path(), "after.txt");
  EXPECT_NE(after.out.find("[ ok ] daily QA: passed today: out/qa/qa-daily-"), std::string::npos)
      << after.out;
}

// safety.require_daily_qa: without today's QA of the room, the loop refuses to start, saying why.
TEST(DailyQaCli, ASceneThatRequiresTheDailyQaIsRefusedWithoutIt) {
  TempDir dir;
  const fs::path fields = qa_phantom_fields(LFTRACK_BIN_PATH, qa_phantom_scene(), dir.path());
  ASSERT_FALSE(fields.empty()) << contents(dir.path() / "precompute.txt");
  std::string text = contents(qa_phantom_scene());
  const std::string safety = "safety:\n";
  ASSERT_NE(text.find(safety), std::string::npos);
  text.replace(text.find(safety), safety.size(), "safety:\n  require_daily_qa: true\n");
  std::ofstream(dir.path() / "strict.yaml") << text;
  const CliRun r = shell(quoted(LFTRACK_BIN_PATH) + " -q " + qa_phantom_loop() +
                             " --check --rt ignore --scene strict.yaml --lf-dir " + quoted(fields.string()),
                         dir.path());
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("[FAIL] daily QA: none of this room today"), std::string::npos) << r.out;
  std::string bad = text;
  bad.replace(bad.find("require_daily_qa: true"), 22, "require_daily_qa: sometimes");
  std::ofstream(dir.path() / "bad.yaml") << bad;
  const CliRun refused =
      shell(quoted(LFTRACK_BIN_PATH) + " -q run --check --scene bad.yaml", dir.path(), "bad.txt");
  EXPECT_EQ(refused.exit_code, 1) << refused.out;
  EXPECT_NE(refused.out.find("require_daily_qa"), std::string::npos) << refused.out;
}

// Ctrl-C during the QA: it ends after the step in progress, says so, fails every check it did not
// make, and writes its (failed) report; the program exits 1, not killed by the signal.
TEST(DailyQaCli, CtrlCEndsTheQaAfterItsStepWithTheReportWritten) {
  TempDir dir;
  const fs::path fields = qa_phantom_fields(LFTRACK_BIN_PATH, qa_phantom_scene(), dir.path());
  ASSERT_FALSE(fields.empty()) << contents(dir.path() / "precompute.txt");
  const fs::path reports = dir.path() / "qa";
  ChildProcess qa({LFTRACK_BIN_PATH, "qa", "daily", "--scene", qa_phantom_scene().string(), "--lf-dir",
                   fields.string(), "--out", reports.string(), "--latency-cycles", "0"});
  std::optional<std::string> line;
  while ((line = qa.read_line(std::chrono::minutes(2))) && line->rfind("offset", 0) != 0) {
  }
  ASSERT_TRUE(line.has_value()) << "the first shift's line";
  qa.signal(SIGINT);
  std::string rest;
  while ((line = qa.read_line(std::chrono::minutes(2)))) rest += *line + "\n";
  EXPECT_EQ(qa.wait(std::chrono::seconds(30)), 1) << rest;
  EXPECT_NE(rest.find("offset (+5.0, -5.0, +5.0) mm, (+0.50, -0.50, +0.50) deg: not run"), std::string::npos)
      << "the shifts after it are not run: " << rest;
  EXPECT_NE(rest.find("daily QA FAILED"), std::string::npos) << rest;
  std::string json;
  for (const auto& entry : fs::directory_iterator(reports))
    if (entry.path().extension() == ".json") json = contents(entry.path());
  EXPECT_NE(json.find("interrupted by the operator"), std::string::npos) << "the report is written: " << json;
}

}  // namespace
}  // namespace lftrack::test
