// The host as rt-check reports it: CPU lists, the CPUs this process may run on, the kernel's
// preemption model and its real-time throttling.

#include <sched.h>
#include <sys/utsname.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "lftrack/rt_check/wakeup_latency.hpp"
#include "rt_check_text.hpp"

namespace lftrack::rt_check {

namespace {
constexpr int kMaxCpuNumber = 4095;
}  // namespace

namespace rt_check_text {

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

// The first line of a small file, or nothing.
std::optional<std::string> read_first_line(const char* path) {
  std::ifstream in(path);
  std::string line;
  if (!in || !std::getline(in, line)) return std::nullopt;
  return line;
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

}  // namespace rt_check_text

using rt_check_text::read_first_line;

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

}  // namespace lftrack::rt_check
