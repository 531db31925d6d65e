#pragma once
// The daily QA's dated report (issue 59): JSON for programs, HTML with a picture for the
// physicist, both in the room's QA folder (out/qa by default, beside out/run's journals), named
// qa-daily-DATE-TIME(.json|.html) (qa-e2e-... for the end-to-end test), never replacing an earlier
// one. `lftrack run` looks there for
// today's passed QA of its scene.

#include <filesystem>
#include <optional>
#include <string>

#include "lftrack/qa/daily_qa_report.hpp"
#include "lftrack/session/preflight.hpp"

namespace lftrack::qa {

inline constexpr const char* kDefaultQaFolder = "out/qa";

struct WrittenReport {
  std::filesystem::path json, html;
};

// Whether reports can be written into `folder` (created if missing; a file is created there and
// removed): checked before a QA runs, so that its minutes are not lost to a folder that refuses.
Status check_report_folder(const std::filesystem::path& folder);

// Writes both files into `folder` (created); a name taken already gets -2, -3, ... (daily and
// end-to-end reports alike: report.kind).
Result<WrittenReport> write_daily_qa_report(const DailyQaReport& report, const std::filesystem::path& folder);

// Today's daily QA of a room as `lftrack run` judges it: the newest daily report in `folder` for
// the room (session::room_fingerprint, hex) dated `date` (the host's local date) decides; it counts
// only if it passed and was the standard QA. Reports that do not parse, symbolic links and files
// of the wrong types are skipped.
struct DailyQaStatus {
  bool passed = false;
  std::filesystem::path file;  // the newest report of the day; empty: none
  std::string detail;          // for the checklist: what was found
};
DailyQaStatus daily_qa_status(const std::filesystem::path& folder, const std::string& room,
                              const std::string& date);

// `lftrack run`'s start-up check "daily QA" for `scene`'s room, today: ok when passed, else a
// warning, or a failure where the scene sets safety.require_daily_qa.
session::PreflightItem daily_qa_item(const session::Scene& scene,
                                     const std::filesystem::path& folder = kDefaultQaFolder);

}  // namespace lftrack::qa
