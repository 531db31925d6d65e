#pragma once
// Real-time set-up of the cycle's thread (DESIGN.md, "One cycle"): lock all memory (mlockall),
// SCHED_FIFO at a priority, and an affinity to the scene's CPUs. With `enforce` a step that
// fails refuses the start and says why (a treatment-room host); without it each failure is a
// warning and the loop runs as an ordinary process (tests, CI, a laptop).

#include <string>
#include <vector>

#include "lftrack/loop/loop_spec.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::host {

struct RealtimeReport {
  bool memory_locked = false;
  bool fifo = false;
  bool affinity = false;
  bool offline = false;  // not applied: a run on a simulated clock takes normal scheduling
  std::vector<std::string> warnings;  // what failed (ignore mode)
  std::string summary() const;
};

// Applies `spec` to the calling thread (and locks the process's memory). Enforce: the first
// failure is returned as an error with the reason and what to change (capabilities, limits).
Result<RealtimeReport> apply_realtime_setup(const RealtimeSpec& spec);

// For a helper thread made after the set-up (it inherited the cycle's policy) that must never
// delay the cycle: under SCHED_FIFO/RR it drops to `below` priority levels under the one it
// inherited (at least 1), so it runs whenever the cycle's threads wait and never preempts
// them; under SCHED_OTHER nothing changes. Returns false if the change was refused.
bool lower_current_thread_priority(int below = 1);
// For a thread whose work may wait (journal and archive writers with deep queues): back to
// SCHED_OTHER, sharing the CPU with ordinary processes.
bool make_current_thread_best_effort();

}  // namespace lftrack::host
