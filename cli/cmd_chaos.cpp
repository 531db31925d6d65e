// `lftrack sim --chaos SEED`: the chaos soak (chaos_soak.hpp) on a scene: faults from the whole
// catalogue at random moments, the safety invariants checked every cycle. Exit 0 when no
// invariant was violated, 1 when any was (each listed) or the soak could not run.

#include <signal.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <atomic>

#include <algorithm>
#include <cstdio>

#include "cli_commands.hpp"
#include "lftrack/chaos/chaos_soak.hpp"
#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using loop::TrackingState;

namespace {

std::atomic<bool> g_interrupt{false};

extern "C" void on_chaos_interrupt(int) {
  g_interrupt.store(true);
}

void print_report(const chaos::ChaosReport& r) {
  std::printf(
      "chaos soak, seed %llu: %lld cycles in %lld segments (%lld over Modbus, %lld over CAN, %lld imaging on "
      "demand), "
      "%.0f s%s\n",
      static_cast<unsigned long long>(r.seed), static_cast<long long>(r.cycles),
      static_cast<long long>(r.segments), static_cast<long long>(r.modbus_segments),
      static_cast<long long>(r.can_segments), static_cast<long long>(r.model_segments), r.wall_s,
      r.interrupted ? ", interrupted" : "");
  std::int64_t total = 0;
  for (std::int64_t n : r.injected) total += n;
  std::printf("faults injected: %lld\n", static_cast<long long>(total));
  for (std::size_t k = 0; k < chaos::kChaosFaultKinds; ++k)
    std::printf("  %-24s %lld\n", to_string(static_cast<chaos::ChaosFault>(k)),
                static_cast<long long>(r.injected[k]));
  std::printf("states at cycle end:");
  for (std::size_t s = 0; s < r.states.size(); ++s)
    if (r.states[s] > 0)
      std::printf(" %s %lld", to_string(static_cast<TrackingState>(s)), static_cast<long long>(r.states[s]));
  std::printf("\ncommands %lld, entries into HOLD %lld and FAULT %lld, overruns %lld; operator: %lld resumes and "
              "%lld resets accepted, %lld commands refused\n",
              static_cast<long long>(r.commands), static_cast<long long>(r.holds), static_cast<long long>(r.faults),
              static_cast<long long>(r.overruns), static_cast<long long>(r.resumes_accepted),
              static_cast<long long>(r.resets_accepted), static_cast<long long>(r.operator_refused));
  if (r.model_segments > 0)
    std::printf(
        "imaging on demand: the surrogate found failed (stopped, jumped, frozen or not finite) in %lld "
        "cycles\n",
        static_cast<long long>(r.surrogate_fault_cycles));
  std::printf("cycles checked %lld (a cycle that threw has no record); journal records read back and checked "
              "%lld, in %s\n",
              static_cast<long long>(r.cycles_checked), static_cast<long long>(r.journal_records),
              r.journal_dir.string().c_str());
  std::printf("invariant violations: %lld\n", static_cast<long long>(r.violation_count));
  for (const chaos::ChaosViolation& v : r.violations)
    std::printf("  segment %lld, cycle %lld: %s\n", static_cast<long long>(v.segment),
                static_cast<long long>(v.cycle), v.what.c_str());
}

}  // namespace

Status run_chaos_command(const SceneOptions& scene, const chaos::ChaosOptions& options, bool json) {
  LFTRACK_RETURN_IF_ERROR(chaos::check_chaos_options(options));
  tracking::ThreadPool pool(scene.threads);
  auto prepared = load_prepared_scene(scene, &pool);
  if (!prepared.ok()) return prepared.status();
  chaos::ChaosOptions o = options;
  if (!json)
    // On a terminal one line rewritten in place; in a log a line at every tenth of the run
    // (every 1,000 cycles without an end).
    o.progress = [terminal = ::isatty(STDERR_FILENO) == 1, last = std::int64_t(-1)](
                     std::int64_t done, std::int64_t total) mutable {
      if (!terminal) {
        const std::int64_t step = total > 0 ? done * 10 / total : done / 1000;
        if (step == last) return;
        last = step;
      }
      const char* start = terminal ? "\r" : "";
      const char* end = terminal && !(total > 0 && done >= total) ? "" : "\n";
      if (total > 0)
        std::fprintf(stderr, "%schaos: %lld of %lld cycles%s", start, static_cast<long long>(done),
                     static_cast<long long>(total), end);
      else
        std::fprintf(stderr, "%schaos: %lld cycles (Ctrl-C ends the soak)%s", start,
                     static_cast<long long>(done), end);
    };
  spdlog::info("chaos soak on {}: {} cycles, seed {}, fault rate {} per cycle, journals in {}",
               prepared->scene.name, o.cycles, o.seed, o.fault_rate, o.journal_dir.string());
  // Each segment's session would say how it was assembled (hundreds of times in a long soak):
  // only warnings and errors while the soak runs.
  const spdlog::level::level_enum level = spdlog::get_level();
  spdlog::set_level(std::max(level, spdlog::level::warn));
  // Ctrl-C or SIGTERM ends the soak after the current cycle, with the report of what ran.
  g_interrupt.store(false);
  o.interrupt = &g_interrupt;
  struct sigaction action {};
  action.sa_handler = on_chaos_interrupt;
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
  auto report = chaos::run_chaos_soak(*prepared, o, &pool);
  spdlog::set_level(level);
  if (!report.ok()) return report.status();
  if (json)
    std::printf("%s\n", to_json(*report).dump(2).c_str());
  else
    print_report(*report);
  if (report->violation_count > 0)
    return failed_precondition("chaos soak: " + std::to_string(report->violation_count) + " invariant violations");
  if (report->interrupted) return failed_precondition("chaos soak interrupted after " + std::to_string(report->cycles) + " cycles");
  return {};
}

}  // namespace lftrack::cli
