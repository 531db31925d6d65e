#pragma once
// The loop's schedule: cycle k starts at start + k * period on CLOCK_MONOTONIC (absolute
// deadlines, so timing errors do not accumulate). A cycle that ends after the next start is an
// overrun: the periods it ran into are skipped, not caught up with a burst of cycles.

#include <cstdint>

namespace lftrack::loop {

struct NextCycle {
  std::int64_t index = 0;     // cycle index to run next
  std::int64_t start_ns = 0;  // its start time
  std::int64_t skipped = 0;   // periods skipped because the last cycle overran
  bool overrun = false;
};

// After cycle `index` (started at start_ns + index * period_ns) ended at `now_ns`.
NextCycle next_cycle(std::int64_t start_ns, std::int64_t period_ns, std::int64_t index, std::int64_t now_ns);

// Sleeps until `deadline_ns` on CLOCK_MONOTONIC (clock_nanosleep, TIMER_ABSTIME), resuming after
// signals; returns at once if it has passed.
void sleep_until_ns(std::int64_t deadline_ns);
std::int64_t monotonic_now_ns();

}  // namespace lftrack::loop
