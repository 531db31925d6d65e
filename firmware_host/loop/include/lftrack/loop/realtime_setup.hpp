#pragma once
// Real-time set-up of the cycle's thread (DESIGN.md, "One cycle"): lock all memory (mlockall),
// SCHED_FIFO at a priority, and an affinity to the scene's CPUs. A run in enforce mode applies it
// and a step that fails refuses the start and says why (a treatment-room host); a run in ignore
// mode applies none of it (realtime_not_applied: tests, CI, a laptop), nor does a start-up check
// (check_realtime_setup says whether it could be applied).

#include <string>
#include <vector>

#include "lftrack/loop/loop_spec.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::loop {

struct RealtimeReport {
  bool memory_locked = false;  // check_realtime_setup: could be
  bool fifo = false;           // check_realtime_setup: could be taken
  bool affinity = false;       // check_realtime_setup: could be set
  // Why nothing was applied: "offline run on a simulated clock", "loop.realtime.mode: ignore",
  // "a check: nothing applied"; empty when the set-up was applied.
  std::string not_applied;
  bool checked = false;  // check_realtime_setup's report: the three flags say what could be done
  std::vector<std::string> warnings;  // what failed, or would fail (not enforced)
  std::string summary() const;
};

// A run that takes normal scheduling and locks no memory, and why.
RealtimeReport realtime_not_applied(std::string why);

// Applies `spec` to the calling thread (and locks the process's memory). Enforce: the first
// failure is returned as an error with the reason and what to change (capabilities, limits);
// otherwise each failure is a warning (rt-check measures whatever it got).
Result<RealtimeReport> apply_realtime_setup(const RealtimeSpec& spec);

// Whether apply_realtime_setup(spec) could succeed, changing nothing: CAP_IPC_LOCK or an
// unlimited RLIMIT_MEMLOCK for mlockall, CAP_SYS_NICE or RLIMIT_RTPRIO for the priority, and
// spec.cpus within the CPUs this process may use. Enforce: refused with every reason (the
// message says nothing was applied); otherwise each is a warning.
Result<RealtimeReport> check_realtime_setup(const RealtimeSpec& spec);

// For a helper thread made after the set-up (it inherited the cycle's policy) that must never
// delay the cycle: under SCHED_FIFO/RR it drops to `below` priority levels under the one it
// inherited (at least 1), so it runs whenever the cycle's threads wait and never preempts
// them; under SCHED_OTHER nothing changes. Returns false if the change was refused.
bool lower_current_thread_priority(int below = 1);
// For a thread whose work may wait (journal and archive writers with deep queues): back to
// SCHED_OTHER, sharing the CPU with ordinary processes.
bool make_current_thread_best_effort();

}  // namespace lftrack::loop
