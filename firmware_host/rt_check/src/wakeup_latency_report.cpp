// The wake-up latency report: what was in effect, its totals, and its JSON form.

#include <algorithm>

#include "lftrack/rt_check/wakeup_latency.hpp"
#include "rt_check_text.hpp"

namespace lftrack::rt_check {

using rt_check_text::cpu_list_text;

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

}  // namespace lftrack::rt_check
