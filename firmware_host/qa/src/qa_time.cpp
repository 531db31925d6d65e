#include "lftrack/qa/qa_time.hpp"

#include <chrono>
#include <ctime>

namespace lftrack::qa {

QaTime qa_now() {
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm utc{}, local{};
  ::gmtime_r(&now, &utc);
  ::localtime_r(&now, &local);
  char text[64];
  QaTime t;
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &utc);
  t.utc_iso = text;
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%S%z", &local);
  t.local_iso = text;
  std::strftime(text, sizeof text, "%Y-%m-%d", &local);
  t.local_date = text;
  return t;
}

}  // namespace lftrack::qa
