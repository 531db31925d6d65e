#include "lftrack/loop/cycle_schedule.hpp"

#include <time.h>

#include <cerrno>

namespace lftrack::loop {

NextCycle next_cycle(std::int64_t start_ns, std::int64_t period_ns, std::int64_t index, std::int64_t now_ns) {
  NextCycle n;
  n.index = index + 1;
  n.start_ns = start_ns + n.index * period_ns;
  if (now_ns > n.start_ns && period_ns > 0) {
    // The first period start at or after now.
    const std::int64_t late_periods = (now_ns - n.start_ns + period_ns - 1) / period_ns;
    n.overrun = true;
    n.skipped = late_periods;
    n.index += late_periods;
    n.start_ns = start_ns + n.index * period_ns;
  }
  return n;
}

std::int64_t monotonic_now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

void sleep_until_ns(std::int64_t deadline_ns) {
  timespec ts{};
  ts.tv_sec = deadline_ns / 1'000'000'000;
  ts.tv_nsec = deadline_ns % 1'000'000'000;
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

}  // namespace lftrack::loop
