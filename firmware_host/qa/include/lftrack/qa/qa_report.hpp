#pragma once
// The daily QA's dated report (issue 59): JSON for programs, HTML with a picture for the
// physicist, both in the room's QA folder (out/qa by default, beside out/run's journals), named
// qa-daily-DATE-TIME(.json|.html) (qa-e2e-... for the end-to-end test), never replacing an earlier
// one. `lftrack run` looks there for
// today's passed QA of its scene.

#include <filesystem>
#include <optional>
#include <string>

#include "lftrack/qa/daily_qa.hpp"

namespace lftrack::qa {

inline constexpr const char* kDefaultQaFolder = "out/qa";

struct WrittenReport {
  std::filesystem::path json, html;
};

// Writes both files into `folder` (created); a name taken already gets -2, -3, ... (daily and
// end-to-end reports alike: report.kind).
Result<WrittenReport> write_daily_qa_report(const DailyQaReport& report, const std::filesystem::path& folder);

// The newest report in `folder` for the room with `fingerprint` (host::room_fingerprint) dated `date_utc`
// (YYYY-MM-DD) that passed, if any; reports that do not parse are skipped.
std::optional<std::filesystem::path> passed_daily_qa(const std::filesystem::path& folder,
                                                     const std::string& fingerprint,
                                                     const std::string& date_utc);

// Today's date in UTC, YYYY-MM-DD (the day a report counts for).
std::string today_utc();

}  // namespace lftrack::qa
