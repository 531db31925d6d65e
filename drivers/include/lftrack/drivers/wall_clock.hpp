#pragma once
// CLOCK_REALTIME less CLOCK_MONOTONIC, now: how a time stamp on the wall clock (OpenIGTLink's, a
// tracker's) becomes the loop's CLOCK_MONOTONIC and back. Read as monotonic, real, monotonic, up to
// three times, keeping the tightest: a thread preempted between two reads of the clocks would
// otherwise shift every time stamp it converts by the preemption.

#include <time.h>

#include <cstdint>

namespace lftrack::drivers {

inline std::int64_t clock_now_ns(clockid_t clock) {
  timespec ts{};
  clock_gettime(clock, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

inline std::int64_t realtime_minus_monotonic_ns() {
  std::int64_t best = 0, best_gap = -1;
  for (int i = 0; i < 3; ++i) {
    const std::int64_t before = clock_now_ns(CLOCK_MONOTONIC);
    const std::int64_t real = clock_now_ns(CLOCK_REALTIME);
    const std::int64_t after = clock_now_ns(CLOCK_MONOTONIC);
    if (best_gap < 0 || after - before < best_gap) {
      best_gap = after - before;
      best = real - (before + (after - before) / 2);
    }
    if (best_gap < 20'000) break;
  }
  return best;
}

}  // namespace lftrack::drivers
