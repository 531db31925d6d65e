// The wake-up latency measurement: one thread per CPU, woken on a fixed period like cyclictest.
// The report's text and JSON: wakeup_latency_report.cpp; the host's CPUs and kernel:
// host_facts.cpp.

#include "lftrack/rt_check/wakeup_latency.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/utsname.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "lftrack/loop/cycle_schedule.hpp"
#include "lftrack/loop/realtime_setup.hpp"
#include "rt_check_text.hpp"

namespace lftrack::rt_check {

using loop::apply_realtime_setup;
using loop::monotonic_now_ns;
using loop::RealtimeSpec;
using loop::sleep_until_ns;
using rt_check_text::cpu_list_text;
using rt_check_text::number_text;
using rt_check_text::online_cpus;

namespace {

constexpr double kMinIntervalUs = 50;
constexpr double kMaxIntervalUs = 1e6;
constexpr double kMaxDurationS = 3600;
constexpr int kMaxHistogramUs = 1'000'000;
constexpr std::size_t kOverflowKept = 65536;  // overflowed wake-ups kept exactly, for quantiles

std::string policy_name(int policy) {
  switch (policy) {
    case SCHED_OTHER: return "SCHED_OTHER";
    case SCHED_FIFO: return "SCHED_FIFO";
    case SCHED_RR: return "SCHED_RR";
    case SCHED_BATCH: return "SCHED_BATCH";
    case SCHED_IDLE: return "SCHED_IDLE";
#ifdef SCHED_DEADLINE
    case SCHED_DEADLINE: return "SCHED_DEADLINE";
#endif
    default: return "policy " + std::to_string(policy);
  }
}

// VmLck of this process in kB, or -1.
long read_vmlck_kb() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmLck:", 0) == 0) {
      long kb = -1;
      if (std::sscanf(line.c_str() + 6, "%ld", &kb) == 1) return kb;
      return -1;
    }
  }
  return -1;
}

// One measuring thread's state: written by that thread only, read after it is joined.
struct Worker {
  int cpu = -1;
  CpuWakeupLatency result;
  std::vector<std::int64_t> overflow_ns;
  std::int64_t sum_ns = 0;
  std::int64_t min_ns = std::numeric_limits<std::int64_t>::max();
  std::int64_t max_ns = std::numeric_limits<std::int64_t>::min();
  std::int64_t max_at_ns = 0;  // from the start
  Status setup;
  bool stopped = false;
};

// The hand-over between the calling thread and the measuring threads.
struct Start {
  std::mutex mutex;
  std::condition_variable cv;
  int ready = 0;
  int done = 0;
  enum { kWait, kGo, kAbort } state = kWait;
  std::int64_t start_ns = 0;
};

// The thread's own policy, priority and whether its affinity is exactly {cpu}.
void read_back(int cpu, int* policy, int* priority, bool* pinned) {
  sched_param param{};
  *policy = -1;
  *priority = 0;
  if (pthread_getschedparam(pthread_self(), policy, &param) == 0) *priority = param.sched_priority;
  cpu_set_t set;
  CPU_ZERO(&set);
  *pinned = false;
  if (pthread_getaffinity_np(pthread_self(), sizeof set, &set) == 0)
    *pinned = CPU_COUNT(&set) == 1 && cpu >= 0 && cpu < CPU_SETSIZE && CPU_ISSET(cpu, &set);
}

void measure_on_cpu(Worker* w, const WakeupLatencyOptions& o, Start* start) {
  RealtimeSpec spec;
  spec.enforce = o.enforce;
  spec.priority = o.priority;
  spec.cpus = {w->cpu};
  if (auto rt = apply_realtime_setup(spec); rt.ok())
    w->result.warnings = rt->warnings;
  else
    w->setup = rt.status().with_context("CPU " + std::to_string(w->cpu));
  int policy = -1;
  read_back(w->cpu, &policy, &w->result.priority, &w->result.pinned);
  w->result.policy = policy_name(policy);
  const bool fifo_before = policy == SCHED_FIFO && w->result.priority == o.priority;

  std::int64_t start_ns = 0;
  {
    std::unique_lock lock(start->mutex);
    ++start->ready;
    start->cv.notify_all();
    start->cv.wait(lock, [&] { return start->state != Start::kWait; });
    if (start->state == Start::kAbort) return;
    start_ns = start->start_ns;
  }

  // The measurement: nothing in here allocates (the histogram and the overflow list are sized).
  const std::int64_t interval_ns = std::llround(o.interval_us * 1e3);
  const std::int64_t end_ns = o.loops > 0 ? std::numeric_limits<std::int64_t>::max()
                                          : start_ns + std::llround(o.duration_s * 1e9);
  const std::int64_t loops = o.loops > 0 ? o.loops : std::numeric_limits<std::int64_t>::max();
  const std::int64_t bins = static_cast<std::int64_t>(w->result.histogram.size());
  const std::int64_t budget_ns =
      o.budget_us ? std::llround(*o.budget_us * 1e3) : std::numeric_limits<std::int64_t>::max();
  // Counted in locals (this thread's stack), not in the Worker that shares cache lines with its
  // neighbours in the vector, and written back after the run.
  CpuWakeupLatency& r = w->result;
  std::uint64_t* const histogram = r.histogram.data();
  std::int64_t samples = 0, skipped = 0, early = 0, over_budget = 0, wrong_cpu = 0;
  std::uint64_t overflow = 0;
  std::int64_t sum_ns = 0, min_ns = std::numeric_limits<std::int64_t>::max(),
               max_ns = std::numeric_limits<std::int64_t>::min(), max_at_ns = 0;
  std::int64_t intended = 0;
  std::int64_t next = start_ns;
  for (;;) {
    next += interval_ns;
    if (next > end_ns || intended >= loops) break;
    if (o.stop && o.stop->load(std::memory_order_relaxed)) {
      w->stopped = true;
      break;
    }
    sleep_until_ns(next);
    const std::int64_t now = monotonic_now_ns();
    const int on_cpu = sched_getcpu();
    const std::int64_t late = now - next;
    ++intended;
    ++samples;
    sum_ns += late;
    min_ns = std::min(min_ns, late);
    if (late > max_ns) {
      max_ns = late;
      max_at_ns = next - start_ns;
    }
    if (late < 0) ++early;
    if (late > budget_ns) ++over_budget;
    if (on_cpu != w->cpu) ++wrong_cpu;
    const std::int64_t bin = std::max<std::int64_t>(0, late) / 1000;
    if (bin < bins) {
      ++histogram[bin];
    } else {
      ++overflow;
      if (w->overflow_ns.size() < w->overflow_ns.capacity()) w->overflow_ns.push_back(late);
    }
    if (late >= interval_ns) {  // the intervals this wake-up ran into are skipped, not caught up
      const std::int64_t k = late / interval_ns;
      // Counted only where they were planned (within the duration or the loop count).
      const std::int64_t planned = o.loops > 0 ? loops - intended : (end_ns - next) / interval_ns;
      skipped += std::min(k, std::max<std::int64_t>(0, planned));
      next += k * interval_ns;
      intended += k;
    }
  }
  r.samples = samples;
  r.skipped_periods = skipped;
  r.early = early;
  r.over_budget = over_budget;
  r.wrong_cpu = wrong_cpu;
  r.overflow = overflow;
  w->sum_ns = sum_ns;
  w->min_ns = min_ns;
  w->max_ns = max_ns;
  w->max_at_ns = max_at_ns;

  int policy_after = -1, priority_after = 0;
  bool pinned_after = false;
  read_back(w->cpu, &policy_after, &priority_after, &pinned_after);
  r.fifo = fifo_before && policy_after == SCHED_FIFO && priority_after == o.priority;
  r.pinned = r.pinned && pinned_after;
  std::lock_guard lock(start->mutex);
  ++start->done;
  start->cv.notify_all();
}

// The q-quantile's 1 us bin (upper edge, capped at max), or among the overflowed wake-ups.
double quantile_us(const Worker& w, double q) {
  const CpuWakeupLatency& r = w.result;
  if (r.samples == 0) return 0;
  const auto rank = static_cast<std::uint64_t>(std::max(1.0, std::ceil(q * double(r.samples))));
  std::uint64_t seen = 0;
  for (std::size_t i = 0; i < r.histogram.size(); ++i) {
    seen += r.histogram[i];
    if (seen >= rank) return std::min(r.max_us, double(i + 1));
  }
  const std::uint64_t in_overflow = rank - seen;  // 1-based rank among the overflowed wake-ups
  if (in_overflow <= w.overflow_ns.size()) return 1e-3 * double(w.overflow_ns[in_overflow - 1]);
  return r.max_us;
}

void finish_stats(Worker* w) {
  CpuWakeupLatency& r = w->result;
  if (r.samples == 0) return;
  r.min_us = 1e-3 * double(w->min_ns);
  r.max_us = 1e-3 * double(w->max_ns);
  r.max_at_s = 1e-9 * double(w->max_at_ns);
  r.mean_us = 1e-3 * double(w->sum_ns) / double(r.samples);
  std::sort(w->overflow_ns.begin(), w->overflow_ns.end());
  r.p50_us = quantile_us(*w, 0.5);
  r.p99_us = quantile_us(*w, 0.99);
  r.p999_us = quantile_us(*w, 0.999);
}

}  // namespace

Status validate_wakeup_latency_options(const WakeupLatencyOptions& o) {
  if (!std::isfinite(o.interval_us) || o.interval_us < kMinIntervalUs || o.interval_us > kMaxIntervalUs)
    return invalid_argument("interval " + number_text(o.interval_us) +
                            " us: must be from 50 us to 1000000 us (1 s)");
  if (o.loops < 0) return invalid_argument("loops " + std::to_string(o.loops) + ": must not be negative");
  if (o.loops > 0) {
    if (double(o.loops) * o.interval_us * 1e-6 > kMaxDurationS)
      return invalid_argument("loops " + std::to_string(o.loops) + " at " + number_text(o.interval_us) +
                              " us take over 3600 s");
  } else if (!std::isfinite(o.duration_s) || !(o.duration_s > 0) || o.duration_s > kMaxDurationS) {
    return invalid_argument("duration " + number_text(o.duration_s) +
                            " s: must be more than 0 and at most 3600 s");
  } else if (o.duration_s * 1e6 < o.interval_us) {
    return invalid_argument("duration " + number_text(o.duration_s) + " s is shorter than one interval (" +
                            number_text(o.interval_us) + " us)");
  }
  if (o.priority < 1 || o.priority > 99)
    return invalid_argument("priority " + std::to_string(o.priority) + ": SCHED_FIFO priorities are 1 to 99");
  if (o.histogram_max_us < 1 || o.histogram_max_us > kMaxHistogramUs)
    return invalid_argument("histogram limit " + std::to_string(o.histogram_max_us) +
                            " us: must be from 1 to 1000000 us");
  if (o.budget_us && (!std::isfinite(*o.budget_us) || *o.budget_us < 0 || *o.budget_us > kMaxDurationS * 1e6))
    return invalid_argument("budget " + number_text(*o.budget_us) + " us: must be from 0 to 3600 s");
  const std::vector<int> online = online_cpus();
  const std::vector<int> allowed = allowed_cpus();
  std::set<int> seen;
  for (int cpu : o.cpus) {
    if (std::find(online.begin(), online.end(), cpu) == online.end())
      return invalid_argument("CPU " + std::to_string(cpu) + " does not exist or is offline (online: " +
                              cpu_list_text(online) + ")");
    if (std::find(allowed.begin(), allowed.end(), cpu) == allowed.end())
      return invalid_argument("CPU " + std::to_string(cpu) + " is not in this process's affinity mask (allowed: " +
                              cpu_list_text(allowed) + ")");
    if (!seen.insert(cpu).second) return invalid_argument("CPU " + std::to_string(cpu) + " is named twice");
  }
  if (o.cpus.empty() && allowed.empty()) return failed_precondition("sched_getaffinity names no CPU");
  return {};
}

Result<WakeupLatencyReport> measure_wakeup_latency(const WakeupLatencyOptions& options) {
  LFTRACK_RETURN_IF_ERROR(validate_wakeup_latency_options(options));
  const std::vector<int> cpus = options.cpus.empty() ? allowed_cpus() : options.cpus;
  const long vmlck_before = read_vmlck_kb();

  WakeupLatencyReport report;
  report.interval_us = options.interval_us;
  report.planned_s = options.loops > 0 ? double(options.loops) * options.interval_us * 1e-6 : options.duration_s;
  report.priority = options.priority;
  report.histogram_max_us = options.histogram_max_us;
  report.budget_us = options.budget_us;
  report.load_note = options.load_note;

  std::vector<Worker> workers(cpus.size());
  for (std::size_t i = 0; i < cpus.size(); ++i) {
    workers[i].cpu = workers[i].result.cpu = cpus[i];
    workers[i].result.histogram.assign(static_cast<std::size_t>(options.histogram_max_us), 0);
    workers[i].overflow_ns.reserve(kOverflowKept);
  }
  Start start;
  std::vector<std::thread> threads;
  threads.reserve(workers.size());
  for (auto& w : workers) threads.emplace_back(measure_on_cpu, &w, std::cref(options), &start);

  // Every thread set up (or refused): go, or abort on the first refusal under `enforce`.
  Status refused;
  {
    std::unique_lock lock(start.mutex);
    start.cv.wait(lock, [&] { return start.ready == int(workers.size()); });
    for (const auto& w : workers)
      if (!w.setup.ok() && refused.ok()) refused = w.setup;
    report.vmlck_kb = read_vmlck_kb();
    report.memory_locked = report.vmlck_kb > 0;
    if (!refused.ok()) {
      start.state = Start::kAbort;
    } else {
      start.state = Start::kGo;
      start.start_ns = monotonic_now_ns() + 10'000'000;  // 10 ms for every thread to reach its sleep
    }
  }
  start.cv.notify_all();

  const auto t0 = std::chrono::steady_clock::now();
  if (refused.ok()) {
    std::unique_lock lock(start.mutex);
    while (!start.cv.wait_for(lock, std::chrono::milliseconds(200),
                              [&] { return start.done == int(workers.size()); })) {
      if (options.progress) {
        const double elapsed = 1e-9 * double(monotonic_now_ns() - start.start_ns);
        lock.unlock();
        options.progress(std::clamp(elapsed / report.planned_s, 0.0, 1.0));
        lock.lock();
      }
    }
  }
  for (auto& t : threads) t.join();
  report.elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // Leave the process's memory as it was found: unlocked if nothing was locked before.
  if (report.memory_locked && vmlck_before == 0) munlockall();
  if (!refused.ok()) return refused;
  if (options.progress) options.progress(1.0);

  for (auto& w : workers) {
    finish_stats(&w);
    report.stopped_early = report.stopped_early || w.stopped;
    report.cpus.push_back(std::move(w.result));
  }
  return report;
}

}  // namespace lftrack::rt_check
