#include "lftrack/loop/realtime_setup.hpp"

#include <linux/capability.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/resource.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

namespace lftrack::loop {

std::string RealtimeReport::summary() const {
  if (checked)
    return std::string("nothing applied (a check): memory ") + (memory_locked ? "can" : "cannot") + " be locked, " +
           "SCHED_FIFO " + (fifo ? "can" : "cannot") + " be taken, " + (affinity ? "pinning allowed" : "not pinned");
  if (!not_applied.empty()) return "not applied (" + not_applied + "): normal scheduling, memory not locked";
  std::string s = std::string("memory ") + (memory_locked ? "locked" : "not locked") + ", " +
                  (fifo ? "SCHED_FIFO" : "normal scheduling") + ", " + (affinity ? "pinned" : "not pinned");
  return s;
}

RealtimeReport realtime_not_applied(std::string why) {
  RealtimeReport report;
  report.not_applied = std::move(why);
  return report;
}

namespace {

// Whether the process holds `capability` in its effective set (/proc/self/status, CapEff).
bool has_capability(int capability) {
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);) {
    if (line.rfind("CapEff:", 0) != 0) continue;
    const unsigned long long mask = std::strtoull(line.c_str() + 7, nullptr, 16);
    return ((mask >> capability) & 1ULL) != 0;
  }
  return false;
}

std::string limit_text(rlim_t limit) {
  return limit == RLIM_INFINITY ? std::string("unlimited") : std::to_string(static_cast<unsigned long long>(limit));
}

// Which limit stands in the way of each step, for the messages: the operator must learn what to
// grant, not read "Operation not permitted".
bool memlock_granted(const rlimit& memlock) {
  return has_capability(CAP_IPC_LOCK) || memlock.rlim_cur == RLIM_INFINITY;
}
std::string memlock_missing(const rlimit& memlock) {
  return "RLIMIT_MEMLOCK is " + limit_text(memlock.rlim_cur) + " bytes, not unlimited, and no CAP_IPC_LOCK";
}
bool rtprio_granted(const rlimit& rtprio, int priority) {
  return has_capability(CAP_SYS_NICE) ||
         (rtprio.rlim_cur == RLIM_INFINITY || rtprio.rlim_cur >= rlim_t(std::max(priority, 0)));
}
std::string rtprio_missing(const rlimit& rtprio) {
  return "RLIMIT_RTPRIO is " + limit_text(rtprio.rlim_cur) + " and no CAP_SYS_NICE";
}
rlimit current_limit(int resource) {
  rlimit limit{};
  ::getrlimit(resource, &limit);
  return limit;
}

// What this process's limits, capabilities and CPUs grant `spec`, and each refused grant in
// words: the memory's apart, since apply_realtime_setup judges memory by trying mlockall (a finite
// RLIMIT_MEMLOCK may hold the whole process).
struct Grants {
  bool memory = false, fifo = false, affinity = false;
  std::string memory_refused;        // empty: granted
  std::vector<std::string> refused;  // the priority and the CPUs
};
Grants judge_grants(const RealtimeSpec& spec) {
  Grants g;
  const rlimit memlock = current_limit(RLIMIT_MEMLOCK);
  const rlimit rtprio = current_limit(RLIMIT_RTPRIO);
  g.memory = memlock_granted(memlock);
  if (!g.memory) g.memory_refused = "mlockall would fail or run out: " + memlock_missing(memlock);
  g.fifo = rtprio_granted(rtprio, spec.priority);
  if (!g.fifo)
    g.refused.push_back("SCHED_FIFO priority " + std::to_string(spec.priority) +
                        " would be refused: " + rtprio_missing(rtprio));
  cpu_set_t allowed;
  CPU_ZERO(&allowed);
  const bool known = ::sched_getaffinity(0, sizeof allowed, &allowed) == 0;
  std::string outside;
  for (int cpu : spec.cpus)
    if (!known || cpu < 0 || cpu >= CPU_SETSIZE || !CPU_ISSET(cpu, &allowed))
      outside += (outside.empty() ? "" : ", ") + std::to_string(cpu);
  g.affinity = !spec.cpus.empty() && outside.empty();
  if (spec.cpus.empty())
    g.refused.push_back("loop.realtime.cpus names no CPU to pin the cycle to");
  else if (!outside.empty())
    g.refused.push_back("CPU affinity would be refused: CPU " + outside + " not among this process's CPUs");
  return g;
}

std::string joined(const std::vector<std::string>& reasons) {
  std::string text;
  for (const std::string& r : reasons) text += (text.empty() ? "" : "; ") + r;
  return text;
}

// What to change, named for each way a host grants it.
std::string remedy(const RealtimeSpec& spec) {
  const std::string p = std::to_string(spec.priority);
  return "grant them: as the lftrack@.service unit does (LimitMEMLOCK=infinity, LimitRTPRIO=" + p +
         " or more, CPUAffinity= including the scene's loop.realtime.cpus), or for a login in "
         "/etc/security/limits.conf (memlock unlimited, rtprio " +
         p + "), or CAP_IPC_LOCK and CAP_SYS_NICE; or set loop.realtime.mode: ignore / --rt ignore";
}

}  // namespace

Result<RealtimeReport> check_realtime_setup(const RealtimeSpec& spec) {
  RealtimeReport report;
  report.checked = true;
  report.not_applied = "a check: nothing applied";
  const Grants g = judge_grants(spec);
  report.memory_locked = g.memory;
  report.fifo = g.fifo;
  report.affinity = g.affinity;
  if (!g.memory_refused.empty()) report.warnings.push_back(g.memory_refused);
  report.warnings.insert(report.warnings.end(), g.refused.begin(), g.refused.end());
  if (spec.enforce && !report.warnings.empty())
    return failed_precondition(
        "real-time set-up (loop.realtime.mode: enforce) could not be applied (a check: "
        "nothing applied): " +
        joined(report.warnings) + "; " + remedy(spec));
  return report;
}

Result<RealtimeReport> apply_realtime_setup(const RealtimeSpec& spec) {
  RealtimeReport report;
  // Enforced: every grant the limits refuse is named together, so one refused start tells the
  // operator all there is to change. Memory is judged by trying: a finite RLIMIT_MEMLOCK may hold
  // the whole process.
  const std::vector<std::string> refused =
      spec.enforce ? judge_grants(spec).refused : std::vector<std::string>{};
  auto enforced = [&](const std::string& reasons) {
    return failed_precondition("real-time set-up (loop.realtime.mode: enforce): " + reasons + "; " +
                               remedy(spec));
  };
  auto failed = [&](const std::string& what) -> Status {
    if (!spec.enforce) {
      report.warnings.push_back(what);
      return {};
    }
    return enforced(refused.empty() ? what : what + "; " + joined(refused));
  };
  if (::mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
    report.memory_locked = true;
  } else {
    const int e = errno;
    const rlimit memlock = current_limit(RLIMIT_MEMLOCK);
    LFTRACK_RETURN_IF_ERROR(
        failed(std::string("memory cannot be locked (mlockall: ") + std::strerror(e) + "): " +
               (memlock_granted(memlock) ? "the limit allows it, so the host has too little memory to lock"
                                         : memlock_missing(memlock))));
  }
  if (!refused.empty()) return enforced(joined(refused));
  sched_param param{};
  param.sched_priority = spec.priority;
  // A process started with the reset-on-fork flag (systemd's CPUSchedulingResetOnFork=) keeps it:
  // without CAP_SYS_NICE the kernel refuses a change that would clear it.
  const int current = ::sched_getscheduler(0);
  const int keep = current >= 0 ? (current & SCHED_RESET_ON_FORK) : 0;
  if (::sched_setscheduler(0, SCHED_FIFO | keep, &param) == 0) {
    report.fifo = true;
  } else {
    const int e = errno;
    const rlimit rtprio = current_limit(RLIMIT_RTPRIO);
    LFTRACK_RETURN_IF_ERROR(failed(
        "SCHED_FIFO priority " + std::to_string(spec.priority) + " refused (" + std::strerror(e) + "): " +
        (rtprio_granted(rtprio, spec.priority)
             ? std::string("the limit allows it, so the kernel's real-time budget refuses (the cgroup's "
                           "cpu.rt_runtime_us, or kernel.sched_rt_runtime_us)")
             : rtprio_missing(rtprio))));
  }
  if (!spec.cpus.empty()) {
    cpu_set_t set;
    CPU_ZERO(&set);
    for (int cpu : spec.cpus) CPU_SET(cpu, &set);
    if (const int e = ::pthread_setaffinity_np(::pthread_self(), sizeof set, &set); e == 0) {
      report.affinity = true;
    } else {
      LFTRACK_RETURN_IF_ERROR(failed(std::string("CPU affinity refused (") + std::strerror(e) +
                                     "): loop.realtime.cpus names a CPU this process may not use "
                                     "(a service's CPUAffinity=, a cgroup's cpuset, or taskset)"));
    }
  }  // enforced without CPUs: refused above ("names no CPU to pin the cycle to")
  return report;
}

bool lower_current_thread_priority(int below) {
  const int policy = ::sched_getscheduler(0);
  sched_param param{};
  if (policy < 0 || ::sched_getparam(0, &param) != 0) return false;
  const int base = policy & ~SCHED_RESET_ON_FORK;
  if (base != SCHED_FIFO && base != SCHED_RR) return true;
  param.sched_priority = std::max(1, param.sched_priority - below);
  return ::sched_setscheduler(0, policy, &param) == 0;  // the reset-on-fork flag kept (see above)
}

bool make_current_thread_best_effort() {
  const int policy = ::sched_getscheduler(0);
  if (policy < 0) return false;
  if ((policy & ~SCHED_RESET_ON_FORK) == SCHED_OTHER) return true;
  sched_param param{};
  param.sched_priority = 0;
  return ::sched_setscheduler(0, SCHED_OTHER | (policy & SCHED_RESET_ON_FORK), &param) == 0;
}

}  // namespace lftrack::loop
