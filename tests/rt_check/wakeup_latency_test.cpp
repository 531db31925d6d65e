// The wake-up latency measurement (wakeup_latency.hpp): short runs whose figures are consistent
// with themselves, every invalid option refused, and what was in effect read back honestly. No
// latency bound is asserted: the machine running the tests is shared and noisy.

#include "lftrack/rt_check/wakeup_latency.hpp"

#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/utsname.h>

#include <cmath>
#include <fstream>
#include <limits>
#include <numeric>
#include <string>
#include <thread>

namespace lftrack::rt_check {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// Whether a fresh thread of this process gets SCHED_FIFO at `priority`, read back with
// sched_getscheduler (independently of the library under test).
bool process_can_take_fifo(int priority) {
  bool fifo = false;
  std::thread probe([&] {
    sched_param p{};
    p.sched_priority = priority;
    pthread_setschedparam(pthread_self(), SCHED_FIFO, &p);
    fifo = sched_getscheduler(0) == SCHED_FIFO;
  });
  probe.join();
  return fifo;
}

long vmlck_kb() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmLck:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}

WakeupLatencyOptions short_run() {
  WakeupLatencyOptions o;
  o.interval_us = 1000;
  o.duration_s = 0.3;
  o.priority = 10;
  o.budget_us = 50;
  return o;
}

void expect_consistent(const CpuWakeupLatency& c, std::int64_t planned) {
  SCOPED_TRACE("CPU " + std::to_string(c.cpu));
  EXPECT_EQ(c.samples + c.skipped_periods, planned) << "every planned wake-up is measured or counted as skipped";
  EXPECT_GE(c.samples, planned / 2) << "sanity: most wake-ups of a short run come";
  EXPECT_EQ(c.early, 0) << "clock_nanosleep never wakes before the absolute time";
  EXPECT_GE(c.min_us, 0.0);
  EXPECT_LE(c.min_us, c.p50_us);
  EXPECT_LE(c.p50_us, c.p99_us);
  EXPECT_LE(c.p99_us, c.p999_us);
  EXPECT_LE(c.p999_us, c.max_us);
  EXPECT_GE(c.mean_us, c.min_us);
  EXPECT_LE(c.mean_us, c.max_us);
  const std::uint64_t in_bins = std::accumulate(c.histogram.begin(), c.histogram.end(), std::uint64_t{0});
  EXPECT_EQ(in_bins + c.overflow, static_cast<std::uint64_t>(c.samples)) << "histogram counts sum to the samples";
  // The histogram agrees with min and max: nothing below min's bin or above max's.
  for (std::size_t i = 0; i < c.histogram.size(); ++i) {
    if (c.histogram[i] == 0) continue;
    EXPECT_GE(double(i) + 1, c.min_us);
    EXPECT_LE(double(i), c.max_us);
  }
  EXPECT_GE(c.over_budget, 0);
  EXPECT_LE(c.over_budget, c.samples);
  EXPECT_EQ(c.wrong_cpu, c.pinned ? 0 : c.wrong_cpu) << "a pinned thread wakes on its CPU";
}

TEST(WakeupLatency, AShortRunIsConsistentWithItsDurationAndInterval) {
  const WakeupLatencyOptions o = short_run();
  auto r = measure_wakeup_latency(o);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_EQ(r->cpus.size(), allowed_cpus().size()) << "no CPUs named: one thread per CPU of the affinity mask";
  for (const auto& c : r->cpus) expect_consistent(c, 300);
  EXPECT_FALSE(r->stopped_early);
  EXPECT_DOUBLE_EQ(r->planned_s, 0.3);
  EXPECT_GE(r->elapsed_s, 0.3);
  EXPECT_EQ(r->samples(), std::accumulate(r->cpus.begin(), r->cpus.end(), std::int64_t{0},
                                          [](std::int64_t n, const auto& c) { return n + c.samples; }));
  double worst = 0;
  for (const auto& c : r->cpus) worst = std::max(worst, c.max_us);
  EXPECT_DOUBLE_EQ(r->max_us(), worst);
}

TEST(WakeupLatency, LoopsCountWakeUpsOnTheNamedCpu) {
  WakeupLatencyOptions o = short_run();
  const int cpu = allowed_cpus().back();
  o.cpus = {cpu};
  o.loops = 400;
  o.interval_us = 500;
  o.duration_s = kNaN;  // ignored when loops are given
  o.histogram_max_us = 5;  // most wake-ups overflow such a small histogram: quantiles still ordered
  auto r = measure_wakeup_latency(o);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  ASSERT_EQ(r->cpus.size(), 1u);
  EXPECT_EQ(r->cpus[0].cpu, cpu);
  EXPECT_EQ(r->cpus[0].histogram.size(), 5u);
  expect_consistent(r->cpus[0], 400);
  EXPECT_DOUBLE_EQ(r->planned_s, 0.2);
}

TEST(WakeupLatency, SaysWhetherFifoAndMemoryLockingWereInEffect) {
  const bool can_fifo = process_can_take_fifo(10);
  const bool can_lock = [] {
    if (vmlck_kb() > 0) return true;
    // As the measurement asks (ASan's shadow memory refuses MCL_FUTURE where MCL_CURRENT passes),
    // and as it checks: by VmLck, since clang's AddressSanitizer makes mlockall a no-op that
    // returns 0.
    const bool ok = mlockall(MCL_CURRENT | MCL_FUTURE) == 0 && vmlck_kb() > 0;
    munlockall();
    return ok;
  }();
  const int caller_policy = sched_getscheduler(0);
  const long locked_before = vmlck_kb();

  auto r = measure_wakeup_latency(short_run());
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_EQ(r->fifo(), can_fifo) << r->in_effect();
  for (const auto& c : r->cpus) {
    EXPECT_EQ(c.fifo, can_fifo);
    EXPECT_EQ(c.policy, can_fifo ? "SCHED_FIFO" : "SCHED_OTHER");
    if (can_fifo) {
      EXPECT_EQ(c.priority, 10);
    } else {
      EXPECT_FALSE(c.warnings.empty()) << "a refused SCHED_FIFO is said, with the reason";
    }
  }
  std::string warnings;
  for (const auto& c : r->cpus)
    for (const auto& w : c.warnings) warnings += "; " + w;
  EXPECT_EQ(r->memory_locked, can_lock) << r->in_effect() << warnings;
  EXPECT_EQ(r->memory_locked, r->vmlck_kb > 0);
  const std::string said = r->in_effect();
  if (can_fifo) {
    EXPECT_EQ(said.rfind("SCHED_FIFO 10 on CPU", 0), 0u) << said;
  } else {
    EXPECT_NE(said.find("NOT real-time"), std::string::npos) << said;
  }
  EXPECT_NE(said.find(can_lock ? "memory locked" : "memory NOT locked"), std::string::npos) << said;

  // The caller is left as it was: its own policy, and no memory left locked.
  EXPECT_EQ(sched_getscheduler(0), caller_policy);
  if (locked_before == 0) {
    EXPECT_EQ(vmlck_kb(), 0);
  }
}

TEST(WakeupLatency, EnforceRefusesWithoutRealtimeOrMeasuresWithIt) {
  WakeupLatencyOptions o = short_run();
  o.duration_s = 0.05;
  o.enforce = true;
  o.cpus = {allowed_cpus().front()};
  auto r = measure_wakeup_latency(o);
  if (process_can_take_fifo(10)) {
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    EXPECT_TRUE(r->fifo());
    EXPECT_TRUE(r->pinned());
  } else {
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("CAP_SYS_NICE"), std::string::npos) << r.status().message();
  }
}

TEST(WakeupLatency, ProgressRisesToOneAndAStopEndsTheRunEarly) {
  WakeupLatencyOptions o = short_run();
  o.duration_s = 30;
  o.cpus = {allowed_cpus().front()};
  std::atomic<bool> stop{false};
  o.stop = &stop;
  std::vector<double> seen;
  o.progress = [&](double f) {
    seen.push_back(f);
    if (seen.size() == 2) stop.store(true);
  };
  auto r = measure_wakeup_latency(o);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_TRUE(r->stopped_early);
  EXPECT_LT(r->elapsed_s, 20.0);
  ASSERT_GE(seen.size(), 2u);
  for (std::size_t i = 0; i < seen.size(); ++i) {
    EXPECT_GE(seen[i], 0.0);
    EXPECT_LE(seen[i], 1.0);
    if (i > 0) {
      EXPECT_GE(seen[i], seen[i - 1]);
    }
  }
  EXPECT_DOUBLE_EQ(seen.back(), 1.0);
  const auto& c = r->cpus[0];
  EXPECT_GT(c.samples, 0);
  EXPECT_LE(c.min_us, c.p50_us);
  EXPECT_LE(c.p999_us, c.max_us);
  EXPECT_EQ(std::accumulate(c.histogram.begin(), c.histogram.end(), std::uint64_t{0}) + c.overflow,
            static_cast<std::uint64_t>(c.samples));
}

// Each invalid option is refused by validation and by the measurement, naming the option.
void expect_refused(const WakeupLatencyOptions& o, const std::string& says) {
  const Status s = validate_wakeup_latency_options(o);
  ASSERT_FALSE(s.ok()) << "expected a refusal saying '" << says << "'";
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find(says), std::string::npos) << s.message();
  EXPECT_FALSE(measure_wakeup_latency(o).ok());
}

TEST(WakeupLatency, EveryInvalidOptionIsRefused) {
  ASSERT_TRUE(validate_wakeup_latency_options(short_run()).ok());
  for (double v : {kNaN, kInf, -kInf, -1000.0, 0.0, 49.0, 1e6 + 1, 1e300}) {
    WakeupLatencyOptions o = short_run();
    o.interval_us = v;
    expect_refused(o, "interval");
  }
  for (double v : {kNaN, kInf, -kInf, -1.0, 0.0, 3600.5, 1e300}) {
    WakeupLatencyOptions o = short_run();
    o.duration_s = v;
    expect_refused(o, "duration");
  }
  {
    WakeupLatencyOptions o = short_run();
    o.duration_s = 0.0001;  // shorter than one 1000 us interval
    expect_refused(o, "shorter than one interval");
  }
  for (std::int64_t v : {std::int64_t{-1}, std::int64_t{3'600'001}, std::numeric_limits<std::int64_t>::max()}) {
    WakeupLatencyOptions o = short_run();
    o.loops = v;
    expect_refused(o, "loops");
  }
  for (int v : {0, -5, 100, std::numeric_limits<int>::max()}) {
    WakeupLatencyOptions o = short_run();
    o.priority = v;
    expect_refused(o, "priority");
  }
  for (int v : {0, -1, 1'000'001}) {
    WakeupLatencyOptions o = short_run();
    o.histogram_max_us = v;
    expect_refused(o, "histogram");
  }
  for (double v : {kNaN, kInf, -1.0, 1e300}) {
    WakeupLatencyOptions o = short_run();
    o.budget_us = v;
    expect_refused(o, "budget");
  }
  for (int v : {-1, 4096, 1 << 30}) {
    WakeupLatencyOptions o = short_run();
    o.cpus = {v};
    expect_refused(o, "does not exist");
  }
  {
    WakeupLatencyOptions o = short_run();
    o.cpus = {allowed_cpus().front(), allowed_cpus().front()};
    expect_refused(o, "named twice");
  }
}

TEST(WakeupLatency, ACpuOutsideTheAffinityMaskIsRefused) {
  const std::vector<int> allowed = allowed_cpus();
  if (allowed.size() < 2) GTEST_SKIP() << "needs two CPUs in the affinity mask";
  // In a thread restricted to the first CPU, the second is outside the (thread's) mask.
  std::thread t([&] {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(allowed[0], &set);
    ASSERT_EQ(pthread_setaffinity_np(pthread_self(), sizeof set, &set), 0);
    WakeupLatencyOptions o = short_run();
    o.cpus = {allowed[1]};
    expect_refused(o, "not in this process's affinity mask");
    o.cpus = {};
    auto r = measure_wakeup_latency(o);
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    ASSERT_EQ(r->cpus.size(), 1u) << "no CPUs named: the caller's mask";
    EXPECT_EQ(r->cpus[0].cpu, allowed[0]);
  });
  t.join();
}

TEST(WakeupLatency, CpuListsParseAndBadOnesAreRefused) {
  auto a = parse_cpu_list("0,2-4, 7");
  ASSERT_TRUE(a.ok()) << a.status().to_string();
  EXPECT_EQ(*a, (std::vector<int>{0, 2, 3, 4, 7}));
  EXPECT_EQ(*parse_cpu_list("3"), std::vector<int>{3});
  for (const char* bad : {"", " ", "a", "1,", ",1", "1,,2", "3-1", "1-", "-1", "1.5", "99999", "0-5000", "1e3"}) {
    auto r = parse_cpu_list(bad);
    EXPECT_FALSE(r.ok()) << "'" << bad << "'";
    if (!r.ok()) {
      EXPECT_NE(r.status().message().find("CPU list"), std::string::npos);
    }
  }
}

TEST(WakeupLatency, JsonCarriesTheFiguresAndWhatWasInEffect) {
  WakeupLatencyOptions o = short_run();
  o.duration_s = 0.05;
  o.cpus = {allowed_cpus().front()};
  o.load_note = "idle";
  auto r = measure_wakeup_latency(o);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  const nlohmann::json j = to_json(*r);
  for (const char* key : {"interval_us", "planned_s", "elapsed_s", "priority", "budget_us", "fifo", "pinned",
                          "memory_locked", "vmlck_kb", "in_effect", "samples", "max_us", "over_budget", "cpus"})
    EXPECT_TRUE(j.contains(key)) << key;
  EXPECT_EQ(j["load_note"], "idle");
  EXPECT_EQ(j["fifo"].get<bool>(), r->fifo());
  ASSERT_EQ(j["cpus"].size(), 1u);
  const auto& c = j["cpus"][0];
  for (const char* key : {"cpu", "samples", "min_us", "mean_us", "p50_us", "p99_us", "p999_us", "max_us",
                          "over_budget", "overflow", "fifo", "policy", "pinned", "histogram"})
    EXPECT_TRUE(c.contains(key)) << key;
  std::uint64_t sum = c["overflow"].get<std::uint64_t>();
  for (const auto& bin : c["histogram"]) sum += bin[1].get<std::uint64_t>();
  EXPECT_EQ(sum, c["samples"].get<std::uint64_t>());
}

TEST(WakeupLatency, KernelPreemptionAgreesWithUname) {
  const KernelPreemption k = read_kernel_preemption();
  utsname u{};
  ASSERT_EQ(uname(&u), 0);
  EXPECT_EQ(k.release, u.release);
  EXPECT_EQ(k.version, u.version);
  const std::string v = u.version;
  std::ifstream rt("/sys/kernel/realtime");
  int flag = 0;
  const bool rt_flag = rt && (rt >> flag) && flag == 1;
  EXPECT_EQ(k.preempt_rt, rt_flag || v.find("PREEMPT_RT") != std::string::npos ||
                              v.find("PREEMPT RT") != std::string::npos);
  EXPECT_FALSE(k.model.empty());
  EXPECT_NE(k.summary().find(k.preempt_rt ? "PREEMPT_RT" : "without PREEMPT_RT"), std::string::npos);
}

}  // namespace
}  // namespace lftrack::rt_check
