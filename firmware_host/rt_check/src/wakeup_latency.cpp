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

namespace lftrack::host {

namespace {

constexpr double kMinIntervalUs = 50;
constexpr double kMaxIntervalUs = 1e6;
constexpr double kMaxDurationS = 3600;
constexpr int kMaxHistogramUs = 1'000'000;
constexpr std::size_t kOverflowKept = 65536;  // overflowed wake-ups kept exactly, for quantiles
constexpr int kMaxCpuNumber = 4095;

std::string number_text(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%g", v);
  return buffer;
}

std::string cpu_list_text(const std::vector<int>& cpus) {
  std::string s;
  for (std::size_t i = 0; i < cpus.size(); ++i) {
    if (i) s += ',';  // (GCC 12 -O3 warns falsely on `"," + std::to_string(...)`)
    s += std::to_string(cpus[i]);
  }
  return s.empty() ? "none" : s;
}

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

// The first line of a small file, or nothing.
std::optional<std::string> read_first_line(const char* path) {
  std::ifstream in(path);
  std::string line;
  if (!in || !std::getline(in, line)) return std::nullopt;
  return line;
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

// The online CPUs (/sys/devices/system/cpu/online), else 0 .. configured - 1.
std::vector<int> online_cpus() {
  if (auto line = read_first_line("/sys/devices/system/cpu/online")) {
    if (auto list = parse_cpu_list(*line); list.ok()) return *list;
  }
  std::vector<int> cpus;
  const long n = sysconf(_SC_NPROCESSORS_CONF);
  for (long i = 0; i < n; ++i) cpus.push_back(static_cast<int>(i));
  return cpus;
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

Result<std::vector<int>> parse_cpu_list(const std::string& text) {
  std::vector<int> cpus;
  auto bad = [&](const std::string& why) -> Status {
    return invalid_argument("CPU list '" + text + "': " + why + " (expected e.g. 0,2-3)");
  };
  auto number = [&](const std::string& item, int* value) -> bool {
    if (item.empty() || item.size() > 6) return false;
    for (char c : item)
      if (c < '0' || c > '9') return false;
    *value = std::stoi(item);
    return true;
  };
  std::string s;
  for (char c : text)
    if (c != ' ' && c != '\n' && c != '\t') s += c;
  if (s.empty()) return bad("names no CPU");
  std::stringstream in(s);
  std::string item;
  while (std::getline(in, item, ',')) {
    if (item.empty()) return bad("an empty item");
    const auto dash = item.find('-');
    int lo = 0, hi = 0;
    if (dash == std::string::npos) {
      if (!number(item, &lo)) return bad("'" + item + "' is not a CPU number");
      hi = lo;
    } else if (!number(item.substr(0, dash), &lo) || !number(item.substr(dash + 1), &hi)) {
      return bad("'" + item + "' is not a range of CPU numbers");
    }
    if (hi < lo) return bad("'" + item + "' is a reversed range");
    if (hi > kMaxCpuNumber) return bad("CPU " + std::to_string(hi) + " is over " + std::to_string(kMaxCpuNumber));
    for (int c = lo; c <= hi; ++c) cpus.push_back(c);
  }
  if (s.back() == ',') return bad("an empty item");
  return cpus;
}

std::vector<int> allowed_cpus() {
  cpu_set_t set;
  CPU_ZERO(&set);
  std::vector<int> cpus;
  if (sched_getaffinity(0, sizeof set, &set) != 0) return cpus;
  for (int c = 0; c < CPU_SETSIZE; ++c)
    if (CPU_ISSET(c, &set)) cpus.push_back(c);
  return cpus;
}

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

bool WakeupLatencyReport::fifo() const {
  return !cpus.empty() && std::all_of(cpus.begin(), cpus.end(), [](const auto& c) { return c.fifo; });
}
bool WakeupLatencyReport::pinned() const {
  return !cpus.empty() && std::all_of(cpus.begin(), cpus.end(), [](const auto& c) { return c.pinned; });
}
double WakeupLatencyReport::max_us() const {
  double m = 0;
  for (const auto& c : cpus)
    if (c.samples > 0) m = std::max(m, c.max_us);
  return m;
}
std::int64_t WakeupLatencyReport::samples() const {
  std::int64_t n = 0;
  for (const auto& c : cpus) n += c.samples;
  return n;
}
std::int64_t WakeupLatencyReport::over_budget() const {
  std::int64_t n = 0;
  for (const auto& c : cpus) n += c.over_budget;
  return n;
}

std::string WakeupLatencyReport::in_effect() const {
  std::vector<int> all;
  for (const auto& c : cpus) all.push_back(c.cpu);
  std::string s;
  if (fifo()) {
    s = "SCHED_FIFO " + std::to_string(priority) + " on CPU" + (cpus.size() > 1 ? "s " : " ") + cpu_list_text(all);
  } else {
    s = "NOT real-time:";
    for (const auto& c : cpus) {
      if (c.fifo) continue;
      s += " CPU " + std::to_string(c.cpu) + " ran " + c.policy +
           (c.policy == "SCHED_FIFO" || c.policy == "SCHED_RR" ? " " + std::to_string(c.priority) : "");
      for (const auto& w : c.warnings)
        if (w.find("SCHED_FIFO") != std::string::npos) s += " (" + w + ")";
      s += ";";
    }
    s.pop_back();
  }
  if (pinned()) {
    s += ", pinned";
  } else {
    s += ", NOT pinned to";
    for (const auto& c : cpus)
      if (!c.pinned) s += " " + std::to_string(c.cpu);
  }
  if (memory_locked)
    s += ", memory locked (VmLck " + std::to_string(vmlck_kb) + " kB)";
  else
    s += vmlck_kb < 0 ? ", memory lock unknown (/proc/self/status unreadable)"
                      : ", memory NOT locked (VmLck " + std::to_string(vmlck_kb) + " kB)";
  return s;
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

nlohmann::json to_json(const WakeupLatencyReport& r) {
  nlohmann::json j;
  j["interval_us"] = r.interval_us;
  j["planned_s"] = r.planned_s;
  j["elapsed_s"] = r.elapsed_s;
  j["stopped_early"] = r.stopped_early;
  j["priority"] = r.priority;
  j["histogram_max_us"] = r.histogram_max_us;
  j["budget_us"] = r.budget_us ? nlohmann::json(*r.budget_us) : nlohmann::json(nullptr);
  j["load_note"] = r.load_note;
  j["fifo"] = r.fifo();
  j["pinned"] = r.pinned();
  j["memory_locked"] = r.memory_locked;
  j["vmlck_kb"] = r.vmlck_kb;
  j["in_effect"] = r.in_effect();
  j["samples"] = r.samples();
  j["max_us"] = r.max_us();
  j["over_budget"] = r.over_budget();
  nlohmann::json cpus = nlohmann::json::array();
  for (const auto& c : r.cpus) {
    nlohmann::json h = nlohmann::json::array();
    for (std::size_t i = 0; i < c.histogram.size(); ++i)
      if (c.histogram[i] > 0) h.push_back({i, c.histogram[i]});
    cpus.push_back({{"cpu", c.cpu},
                    {"samples", c.samples},
                    {"skipped_periods", c.skipped_periods},
                    {"min_us", c.min_us},
                    {"mean_us", c.mean_us},
                    {"p50_us", c.p50_us},
                    {"p99_us", c.p99_us},
                    {"p999_us", c.p999_us},
                    {"max_us", c.max_us},
                    {"max_at_s", c.max_at_s},
                    {"over_budget", c.over_budget},
                    {"overflow", c.overflow},
                    {"early", c.early},
                    {"wrong_cpu", c.wrong_cpu},
                    {"fifo", c.fifo},
                    {"policy", c.policy},
                    {"read_priority", c.priority},
                    {"pinned", c.pinned},
                    {"warnings", c.warnings},
                    {"histogram", h}});
  }
  j["cpus"] = cpus;
  return j;
}

std::string KernelPreemption::summary() const {
  if (preempt_rt) return "PREEMPT_RT (" + release + ")";
  return "without PREEMPT_RT (" + release + ", " + model + ")";
}

KernelPreemption read_kernel_preemption() {
  KernelPreemption k;
  utsname u{};
  if (uname(&u) == 0) {
    k.release = u.release;
    k.version = u.version;
  }
  const auto realtime = read_first_line("/sys/kernel/realtime");
  k.preempt_rt = (realtime && realtime->find('1') != std::string::npos) ||
                 k.version.find("PREEMPT_RT") != std::string::npos ||
                 k.version.find("PREEMPT RT") != std::string::npos;
  if (k.preempt_rt) {
    k.model = "PREEMPT_RT";
  } else if (k.version.find("PREEMPT_DYNAMIC") != std::string::npos) {
    // debugfs shows the current mode as "none voluntary (full) lazy" (root, debugfs mounted).
    std::string mode = "mode not readable";
    if (auto line = read_first_line("/sys/kernel/debug/sched/preempt")) {
      const auto open = line->find('('), close = line->find(')');
      if (open != std::string::npos && close > open) mode = line->substr(open + 1, close - open - 1);
    } else if (auto cmdline = read_first_line("/proc/cmdline")) {
      const auto at = cmdline->find("preempt=");
      if (at != std::string::npos) mode = cmdline->substr(at, cmdline->find(' ', at) - at) + " on the command line";
    }
    k.model = "PREEMPT_DYNAMIC, " + mode;
  } else if (k.version.find("PREEMPT_LAZY") != std::string::npos) {
    k.model = "PREEMPT_LAZY";
  } else if (k.version.find("PREEMPT") != std::string::npos) {
    k.model = "PREEMPT (full)";
  } else {
    k.model = "no forced preemption (PREEMPT_NONE or PREEMPT_VOLUNTARY)";
  }
  auto read_long = [](const char* path, long* value) {
    if (auto line = read_first_line(path)) {
      try {
        *value = std::stol(*line);
      } catch (...) {
      }
    }
  };
  read_long("/proc/sys/kernel/sched_rt_runtime_us", &k.rt_runtime_us);
  read_long("/proc/sys/kernel/sched_rt_period_us", &k.rt_period_us);
  return k;
}

}  // namespace lftrack::host
