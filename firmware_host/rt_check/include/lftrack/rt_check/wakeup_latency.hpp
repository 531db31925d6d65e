#pragma once
// The host's wake-up latency, measured the way cyclictest (rt-tests) measures it, at the loop's
// real-time set-up: one thread per CPU, each given the cycle's set-up by apply_realtime_setup()
// (mlockall, SCHED_FIFO at `priority`, pinned to its one CPU), sleeping with the loop's own
// sleep_until_ns() (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)) to the next interval and
// recording now - intended wake-up. A wake-up later than a whole interval skips the intervals it
// ran into (as cyclictest and the loop's schedule do); they are counted, not measured.
//
// What was in effect is read back, never assumed from what was asked: each measuring thread's
// policy and priority (pthread_getschedparam, before and after its run), its affinity
// (pthread_getaffinity_np) and the CPU of every wake-up (sched_getcpu), and the process's locked
// memory (VmLck in /proc/self/status). Without CAP_SYS_NICE / CAP_IPC_LOCK the measurement runs
// under normal scheduling and the report says so (fifo = false, warnings) unless `enforce` asks
// for a refusal instead.
//
// Unlike cyclictest, /dev/cpu_dma_latency is left alone: the figures are what the loop, which
// does not hold it either, would see. Memory locked by the measurement is unlocked afterwards if
// none was locked before (a library call leaves the process as it found it).

#include <atomic>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "lftrack/tracking/status.hpp"

namespace lftrack::rt_check {

struct WakeupLatencyOptions {
  double interval_us = 1000;  // 50 us .. 1 s
  double duration_s = 10;     // > 0 and <= 3600 s; ignored when `loops` > 0
  std::int64_t loops = 0;     // > 0: this many intended wake-ups per CPU (at most 3600 s of them)
  int priority = 80;          // SCHED_FIFO priority, 1..99 (the scene's loop.realtime.priority)
  // One measuring thread per CPU, pinned to it (the scene's loop.realtime.cpus). Each must exist,
  // be online and be in the calling thread's affinity mask; no repeats. Empty: every CPU of that
  // mask.
  std::vector<int> cpus;
  // Refuse (error, nothing measured) unless mlockall, SCHED_FIFO and the pinning all succeed.
  // Otherwise each failure is a warning and the measurement runs as an ordinary process.
  bool enforce = false;
  int histogram_max_us = 10000;   // 1 us bins from 0 up to this (1 .. 1000000); later: overflow
  std::optional<double> budget_us;  // wake-ups later than this are counted (finite, >= 0)
  std::string load_note;            // what else ran (echoed in the report), e.g. "stress-ng --cpu 1"
  // Called from the calling thread about every 200 ms with the fraction done (0..1).
  std::function<void(double)> progress;
  // Set (from any thread or a signal handler) to end the measurement early; the report keeps the
  // wake-ups measured so far and says it was stopped.
  const std::atomic<bool>* stop = nullptr;
};

// Checks every option (ranges; NaN, infinite, negative and huge values; CPUs against the host and
// the affinity mask); the message names the option, the value and what is allowed.
Status validate_wakeup_latency_options(const WakeupLatencyOptions& options);

struct CpuWakeupLatency {
  int cpu = -1;
  std::int64_t samples = 0;          // wake-ups measured
  std::int64_t skipped_periods = 0;  // intended wake-ups passed over by a wake-up later than an interval
  double min_us = 0, mean_us = 0, max_us = 0;  // exact (ns resolution)
  double max_at_s = 0;  // when the worst wake-up was due, seconds from the start
  // Quantiles: the upper edge of the 1 us bin holding them, capped at max_us; beyond the
  // histogram from the overflowed wake-ups themselves (exact up to 65536 of them, then max_us).
  double p50_us = 0, p99_us = 0, p999_us = 0;
  std::vector<std::uint64_t> histogram;  // histogram[i]: wake-ups i .. i+1 us late
  std::uint64_t overflow = 0;            // wake-ups histogram_max_us or more late
  std::int64_t over_budget = 0;          // wake-ups later than budget_us (0 without a budget)
  std::int64_t early = 0;                // wake-ups before the intended time (0 on a sound kernel)
  std::int64_t wrong_cpu = 0;            // wake-ups that sched_getcpu() found on another CPU
  // Read back in the measuring thread, before and after its run.
  bool fifo = false;  // SCHED_FIFO at the requested priority for the whole run
  std::string policy;  // "SCHED_FIFO", "SCHED_OTHER", ... (as read before the run)
  int priority = 0;    // as read before the run
  bool pinned = false;  // the thread's affinity was exactly {cpu}
  std::vector<std::string> warnings;  // the real-time set-up's refusals for this thread
};

struct WakeupLatencyReport {
  // What was asked.
  double interval_us = 0;
  double planned_s = 0;  // duration_s, or loops * interval
  int priority = 0;
  int histogram_max_us = 0;
  std::optional<double> budget_us;
  std::string load_note;
  // What happened.
  double elapsed_s = 0;
  bool stopped_early = false;
  bool memory_locked = false;  // VmLck > 0 while measuring (read back)
  long vmlck_kb = -1;          // VmLck while measuring (-1: /proc/self/status unreadable)
  std::vector<CpuWakeupLatency> cpus;

  bool fifo() const;    // every thread was SCHED_FIFO at the priority throughout
  bool pinned() const;  // every thread was pinned to its CPU
  double max_us() const;  // the worst wake-up over all CPUs
  std::int64_t samples() const;
  std::int64_t over_budget() const;
  // One line on what was in effect, e.g. "SCHED_FIFO 80 on CPUs 0,1 (pinned), memory locked
  // (VmLck 123456 kB)" or "NOT real-time: normal scheduling (SCHED_FIFO refused: ...), ...".
  std::string in_effect() const;
};

Result<WakeupLatencyReport> measure_wakeup_latency(const WakeupLatencyOptions& options);

// The report as JSON; histograms as [[bin_us, count], ...] of the non-empty bins.
nlohmann::json to_json(const WakeupLatencyReport& report);

// "0,2-4" -> {0, 2, 3, 4}; refuses empty items, negatives, reversed ranges, numbers over 4095.
Result<std::vector<int>> parse_cpu_list(const std::string& text);
// The CPUs the calling thread may run on (sched_getaffinity).
std::vector<int> allowed_cpus();

// The kernel's preemption model, for judging the figures: PREEMPT_RT from /sys/kernel/realtime
// or `uname -v`; PREEMPT_DYNAMIC's current mode where debugfs shows it; RT throttling.
struct KernelPreemption {
  std::string release;  // uname -r
  std::string version;  // uname -v
  bool preempt_rt = false;
  std::string model;  // "PREEMPT_RT", "PREEMPT_DYNAMIC (mode unknown)", "PREEMPT_DYNAMIC (full)", "PREEMPT", ...
  long rt_runtime_us = -2, rt_period_us = -2;  // /proc/sys/kernel/sched_rt_*; -1: unlimited; -2: unread
  std::string summary() const;  // e.g. "without PREEMPT_RT (6.18.44, PREEMPT_DYNAMIC)"
};
KernelPreemption read_kernel_preemption();

}  // namespace lftrack::rt_check
