#include "lftrack/qa/daily_qa_report.hpp"

#include <algorithm>

namespace lftrack::qa {

bool DailyQaReport::passed() const {
  return !checks.empty() &&
         std::all_of(checks.begin(), checks.end(), [](const QaCheck& c) { return c.passed; });
}

}  // namespace lftrack::qa
