#include "lftrack/loop/realtime_setup.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>

#include <cerrno>
#include <cstring>

namespace lftrack::host {

std::string RealtimeReport::summary() const {
  if (offline) return "not applied (offline run on a simulated clock): normal scheduling, memory not locked";
  std::string s = std::string("memory ") + (memory_locked ? "locked" : "not locked") + ", " +
                  (fifo ? "SCHED_FIFO" : "normal scheduling") + ", " + (affinity ? "pinned" : "not pinned");
  return s;
}

Result<RealtimeReport> apply_realtime_setup(const RealtimeSpec& spec) {
  RealtimeReport report;
  auto failed = [&](const std::string& what) -> Status {
    if (spec.enforce)
      return failed_precondition(
          "real-time set-up (loop.realtime.mode: enforce): " + what +
          "; run with CAP_SYS_NICE and CAP_IPC_LOCK (or rtprio and memlock limits in "
          "/etc/security/limits.conf), or set loop.realtime.mode: ignore / --rt ignore");
    report.warnings.push_back(what);
    return {};
  };
  if (::mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
    report.memory_locked = true;
  } else {
    LFTRACK_RETURN_IF_ERROR(failed(std::string("mlockall failed: ") + std::strerror(errno)));
  }
  sched_param param{};
  param.sched_priority = spec.priority;
  if (const int e = ::pthread_setschedparam(::pthread_self(), SCHED_FIFO, &param); e == 0) {
    report.fifo = true;
  } else {
    LFTRACK_RETURN_IF_ERROR(
        failed("SCHED_FIFO priority " + std::to_string(spec.priority) + " refused: " + std::strerror(e)));
  }
  if (!spec.cpus.empty()) {
    cpu_set_t set;
    CPU_ZERO(&set);
    for (int cpu : spec.cpus) CPU_SET(cpu, &set);
    if (const int e = ::pthread_setaffinity_np(::pthread_self(), sizeof set, &set); e == 0) {
      report.affinity = true;
    } else {
      LFTRACK_RETURN_IF_ERROR(failed(std::string("CPU affinity refused: ") + std::strerror(e)));
    }
  } else if (spec.enforce) {
    return failed_precondition(
        "real-time set-up (loop.realtime.mode: enforce): loop.realtime.cpus names no CPU to pin the cycle "
        "to");
  }
  return report;
}

bool lower_current_thread_priority(int below) {
  int policy = 0;
  sched_param param{};
  if (pthread_getschedparam(pthread_self(), &policy, &param) != 0) return false;
  if (policy != SCHED_FIFO && policy != SCHED_RR) return true;
  param.sched_priority = std::max(1, param.sched_priority - below);
  return pthread_setschedparam(pthread_self(), policy, &param) == 0;
}

bool make_current_thread_best_effort() {
  int policy = 0;
  sched_param param{};
  if (pthread_getschedparam(pthread_self(), &policy, &param) != 0) return false;
  if (policy == SCHED_OTHER) return true;
  param.sched_priority = 0;
  return pthread_setschedparam(pthread_self(), SCHED_OTHER, &param) == 0;
}

}  // namespace lftrack::host
