#pragma once
// When a QA ran, as its report says it: the UTC time, and the host's local date, which is the
// clinic's day the QA counts for (a QA at 19:30 in New York belongs to that day, not to the UTC
// day that has begun).

#include <string>

namespace lftrack::qa {

struct QaTime {
  std::string utc_iso;     // 2026-11-30T23:50:01Z
  std::string local_iso;   // 2026-11-30T18:50:01-0500
  std::string local_date;  // 2026-11-30
};

QaTime qa_now();

}  // namespace lftrack::qa
