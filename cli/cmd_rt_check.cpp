// `lftrack rt-check`: the host's wake-up latency at the scene's real-time set-up (SCHED_FIFO
// priority and CPUs from loop.realtime), measured like cyclictest (wakeup_latency.hpp), so that
// a physicist can judge the treatment host before treatment.

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <sstream>

#include "cli_commands.hpp"
#include "lftrack/rt_check/wakeup_latency.hpp"
#include "lftrack/session/progress_bar.hpp"
#include "lftrack/session/scene.hpp"

namespace lftrack::cli {

using session::load_scene;
using session::ProgressBar;

using loop::LoopSpec;

namespace {

namespace fs = std::filesystem;
using rt_check::allowed_cpus;
using rt_check::KernelPreemption;
using rt_check::measure_wakeup_latency;
using rt_check::parse_cpu_list;
using rt_check::read_kernel_preemption;
using rt_check::validate_wakeup_latency_options;
using rt_check::WakeupLatencyOptions;
using rt_check::WakeupLatencyReport;

// Each number is checked when the options are parsed (a value out of range is a usage error,
// exit 2); what depends on the host or on two values together (a CPU that is not there, a
// duration shorter than one interval) is refused after (exit 1).
struct RtCheckOptions {
  std::string scene = "builtin:phantom";
  double duration_s = 10;
  double interval_us = 1000;
  int priority = 0;       // 0: the scene's loop.realtime.priority
  std::string cpus;       // default: the scene's loop.realtime.cpus, else every CPU this process may use
  double budget_us = -1;  // < 0: the cycle's slack (period - acquire_timeout - registration_budget)
  int histogram_max_us = 10000;
  std::string load_note;
  std::string histogram_csv;
  std::string plot_png;
  bool json = false;
  bool require_rt = false;
  bool overwrite = false;  // replace existing --histogram and --plot files
};

std::atomic<bool> g_stop{false};
void on_rt_check_interrupt(int) { g_stop.store(true); }

// --cpus: a list such as 0,2-3 (whether those CPUs are there is the host's to say, after parsing).
CLI::Validator cpu_list() {
  return CLI::Validator(
      [](const std::string& text) -> std::string {
        auto cpus = parse_cpu_list(text);
        return cpus.ok() ? std::string() : cpus.status().message();
      },
      "CPUS");
}

std::string cpus_text(const std::vector<int>& cpus) {
  std::string s;
  for (std::size_t i = 0; i < cpus.size(); ++i) {
    if (i) s += ',';
    s += std::to_string(cpus[i]);
  }
  return s;
}

// Whether a report file may be written at `file`: its folder there, and nothing at it unless
// `overwrite` (a regular file is data; a device or FIFO, such as /dev/stdout on a terminal, is
// written to and replaces nothing). Checked before measuring, so a refusal costs no run.
Status check_output_path(const fs::path& file, const char* option, bool overwrite) {
  const fs::path parent = file.parent_path();
  std::error_code ec;
  if (!parent.empty() && !fs::is_directory(parent, ec))
    return not_found(std::string(option) + " " + file.string() + ": the folder " + parent.string() + " does not exist");
  if (fs::is_symlink(fs::symlink_status(file, ec)))  // written through, it could land anywhere, or nowhere
    return invalid_argument(std::string(option) + " " + file.string() + " is a symbolic link; name the file itself");
  const fs::file_status st = fs::status(file, ec);
  if (fs::is_directory(st)) return invalid_argument(std::string(option) + " " + file.string() + " is a folder");
  if (fs::exists(st) && fs::is_regular_file(st) && !overwrite)
    return failed_precondition(std::string(option) + " " + file.string() + " exists; give --overwrite to replace it");
  return {};
}

// Writes `text` to `file` and checks that every byte reached it (an I/O error, a full disk or
// /dev/full, is an error with the reason). Without `overwrite` a regular file is created, never
// replaced (one made since the check is refused, not overwritten).
Status write_output_file(const fs::path& file, const std::string& text, bool overwrite) {
  std::error_code ec;
  const fs::file_status st = fs::status(file, ec);
  const bool stream = fs::exists(st) && !fs::is_regular_file(st);  // a device or FIFO: written to
  std::FILE* f = std::fopen(file.c_str(), overwrite || stream ? "w" : "wx");
  if (f == nullptr)
    return errno == EEXIST ? failed_precondition(file.string() + " exists; give --overwrite to replace it")
                           : io_error(file.string() + ": cannot write: " + std::strerror(errno));
  const bool written = std::fwrite(text.data(), 1, text.size(), f) == text.size() && std::fflush(f) == 0;
  const int write_errno = errno;
  const bool closed = std::fclose(f) == 0;
  if (!written || !closed)
    return io_error(file.string() + ": write failed: " + std::strerror(written ? errno : write_errno));
  return {};
}

// The histograms: one row per 1 us bin up to the last non-empty one, one column per CPU.
std::string histogram_csv(const WakeupLatencyReport& r) {
  std::ostringstream out;
  std::size_t last = 0;
  for (const auto& c : r.cpus)
    for (std::size_t i = 0; i < c.histogram.size(); ++i)
      if (c.histogram[i] > 0) last = std::max(last, i);
  out << "# lftrack rt-check: wake-ups per 1 us bin [latency_us, latency_us + 1); interval " << r.interval_us
      << " us, SCHED_FIFO priority " << r.priority << " requested; " << r.in_effect() << "\n";
  out << "latency_us";
  for (const auto& c : r.cpus) out << ",cpu" << c.cpu;
  out << "\n";
  for (std::size_t i = 0; i <= last; ++i) {
    out << i;
    for (const auto& c : r.cpus) out << ',' << c.histogram[i];
    out << "\n";
  }
  out << "# overflow (" << r.histogram_max_us << " us or later)";
  for (const auto& c : r.cpus) out << ',' << c.overflow;
  out << "\n";
  return out.str();
}

std::string gp_string(const std::string& s) {
  std::string out = "\"";
  for (char c : s) out += (c == '"' || c == '\\') ? std::string("\\") + c : std::string(1, c);
  return out + "\"";
}
std::string shell_quoted(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

// The plot's data and script beside its PNG: <stem>.dat, <stem>.gp.
fs::path plot_side_file(const fs::path& png, const char* extension) {
  return fs::path(png).replace_extension(extension);
}

// A log-scale histogram per CPU, drawn by gnuplot: <stem>.dat and <stem>.gp next to the PNG (as
// the studies' plots do, so it can be restyled by hand). Both axes are logarithmic so that the
// bulk (microseconds) and the tail (milliseconds) are both readable; an empty bin leaves a gap and
// a lone wake-up a point. (The studies' LinePlot has no log y axis.)
Status draw_histogram_plot(const WakeupLatencyReport& r, const KernelPreemption& kernel, const fs::path& png,
                           bool overwrite) {
  const fs::path dat = plot_side_file(png, ".dat");
  const fs::path gp = plot_side_file(png, ".gp");
  std::size_t last = 0;
  for (const auto& c : r.cpus)
    for (std::size_t i = 0; i < c.histogram.size(); ++i)
      if (c.histogram[i] > 0) last = std::max(last, i);
  {
    std::ostringstream d;
    d << "# latency_us (bin centre)";
    for (const auto& c : r.cpus) d << "\tcpu" << c.cpu;
    d << "\n";
    for (std::size_t i = 0; i <= last; ++i) {
      d << double(i) + 0.5;  // the bin's centre (a log axis has no 0)
      for (const auto& c : r.cpus) d << '\t' << (i < c.histogram.size() ? c.histogram[i] : 0);
      d << "\n";
    }
    LFTRACK_RETURN_IF_ERROR(write_output_file(dat, d.str(), overwrite));
  }
  std::uint64_t overflow = 0;
  for (const auto& c : r.cpus) overflow += c.overflow;
  {
    std::ostringstream g;
    // The x axis reaches the budget, so that the margin to it is seen.
    double x_max = 2.0 * double(last + 1);
    if (r.budget_us && *r.budget_us > 0.5) x_max = std::max(x_max, 1.5 * *r.budget_us);
    char title[512];
    std::snprintf(title, sizeof title, "wake-up latency, %.0f us interval, %.0f s; %s; %s", r.interval_us,
                  r.elapsed_s, r.fifo() ? ("SCHED_FIFO " + std::to_string(r.priority)).c_str() : "NOT SCHED_FIFO",
                  kernel.preempt_rt ? "PREEMPT_RT" : "without PREEMPT_RT");
    g << "set terminal pngcairo size 1000,600 enhanced font 'DejaVu Sans,11'\n"
      << "set output " << gp_string(png.filename().string()) << "\n"
      << "set title " << gp_string(title) << " noenhanced\n"
      << "set xlabel 'wake-up latency (us, 1 us bins)'\nset ylabel 'wake-ups per bin'\n"
      << "set logscale xy\nset yrange [0.7:*]\nset xrange [0.5:" << x_max << "]\n"
      << "set grid\nset key top right box opaque noenhanced\n";
    if (overflow > 0)
      g << "set label 1 " << gp_string(std::to_string(overflow) + " wake-ups " + std::to_string(r.histogram_max_us) +
                                       " us or later (not drawn)")
        << " at graph 0.98, graph 0.75 right\n";
    if (r.budget_us && *r.budget_us > 0.5) {
      g << "set arrow from " << *r.budget_us << ", graph 0 to " << *r.budget_us
        << ", graph 1 nohead dt 2 lw 1.5 lc rgb '#c03020'\n";
      g << "set label 2 " << gp_string("budget " + std::to_string(std::lround(*r.budget_us)) + " us") << " at "
        << *r.budget_us << ", graph 0.3 center rotate by 90 offset -1,0 tc rgb '#c03020'\n";
    }
    g << "plot ";
    for (std::size_t k = 0; k < r.cpus.size(); ++k) {
      const auto& c = r.cpus[k];
      char name[160];
      std::snprintf(name, sizeof name, "CPU %d (max %.1f us)", c.cpu, c.max_us);
      g << (k ? ", \\\n     " : "") << gp_string(dat.filename().string()) << " using 1:($" << k + 2 << ">0?$"
        << k + 2 << ":1/0) with linespoints lw 1.5 pt 7 ps 0.5 title " << gp_string(name);
    }
    g << "\n";
    LFTRACK_RETURN_IF_ERROR(write_output_file(gp, g.str(), overwrite));
  }
  if (std::system("command -v gnuplot >/dev/null 2>&1") != 0) {
    spdlog::warn("gnuplot not found (scripts/setup.sh installs it); wrote {} and {} without drawing them",
                 dat.string(), gp.string());
    return {};
  }
  const std::string dir = gp.parent_path().empty() ? "." : gp.parent_path().string();
  const std::string command =
      "cd " + shell_quoted(dir) + " && gnuplot " + shell_quoted(gp.filename().string()) + " 2>&1";
  if (std::system(command.c_str()) != 0) return io_error("gnuplot failed on " + gp.string());
  return {};
}

void print_table(const WakeupLatencyReport& r) {
  std::printf("%4s %9s %8s %8s %8s %8s %9s %9s %8s %8s %8s  %s\n", "CPU", "samples", "min us", "mean us", "p50 us",
              "p99 us", "p99.9 us", "max us", "max at s", ">budget", "skipped", "policy (read back)");
  for (const auto& c : r.cpus) {
    const bool realtime = c.policy == "SCHED_FIFO" || c.policy == "SCHED_RR";
    std::printf("%4d %9lld %8.1f %8.1f %8.0f %8.0f %9.0f %9.1f %8.2f %8lld %8lld  %s%s%s\n", c.cpu,
                static_cast<long long>(c.samples), c.min_us, c.mean_us, c.p50_us, c.p99_us, c.p999_us, c.max_us,
                c.max_at_s,
                static_cast<long long>(c.over_budget), static_cast<long long>(c.skipped_periods), c.policy.c_str(),
                realtime ? (" " + std::to_string(c.priority)).c_str() : "", c.pinned ? ", pinned" : ", NOT pinned");
    if (c.wrong_cpu > 0)
      std::printf("     %lld wake-ups ran on another CPU\n", static_cast<long long>(c.wrong_cpu));
    if (c.early > 0)
      std::printf("     %lld wake-ups came before the intended time\n", static_cast<long long>(c.early));
  }
}

Status run_rt_check(const RtCheckOptions& o) {
  auto scene = load_scene(o.scene);
  if (!scene.ok()) return scene.status();
  const LoopSpec& loop = scene->loop;

  WakeupLatencyOptions w;
  w.duration_s = o.duration_s;
  w.interval_us = o.interval_us;
  w.priority = o.priority > 0 ? o.priority : loop.realtime.priority;
  w.cpus = loop.realtime.cpus;
  if (!o.cpus.empty()) {
    auto cpus = parse_cpu_list(o.cpus);
    if (!cpus.ok()) return cpus.status().with_context("--cpus");
    w.cpus = *cpus;
  }
  const std::string cpus_from = !o.cpus.empty()             ? "--cpus"
                                : !loop.realtime.cpus.empty() ? "the scene's loop.realtime.cpus"
                                                              : "every CPU this process may use (the scene names none)";
  // The budget a wake-up may take: the cycle's slack beyond the acquisition and registration budgets.
  const double slack_ms = loop.period_ms - loop.acquire_timeout_ms - loop.registration_budget_ms;
  std::string budget_from;
  if (o.budget_us < 0) {
    w.budget_us = std::max(0.0, slack_ms * 1e3);
    char b[200];
    std::snprintf(b, sizeof b,
                  "the cycle's slack: period %g ms - acquire_timeout %g ms - registration_budget %g ms",
                  loop.period_ms, loop.acquire_timeout_ms, loop.registration_budget_ms);
    budget_from = b;
  } else {
    w.budget_us = o.budget_us;
    budget_from = "--budget-us";
  }
  w.histogram_max_us = o.histogram_max_us;
  w.load_note = o.load_note;
  w.enforce = o.require_rt;
  LFTRACK_RETURN_IF_ERROR(validate_wakeup_latency_options(w));
  if (!o.histogram_csv.empty())
    LFTRACK_RETURN_IF_ERROR(check_output_path(o.histogram_csv, "--histogram", o.overwrite));
  if (!o.plot_png.empty()) {
    if (fs::path(o.plot_png).extension() != ".png")
      return invalid_argument("--plot " + o.plot_png + ": must name a .png file");
    for (const fs::path& file : {fs::path(o.plot_png), plot_side_file(o.plot_png, ".dat"), plot_side_file(o.plot_png, ".gp")}) {
      LFTRACK_RETURN_IF_ERROR(check_output_path(file, "--plot", o.overwrite));
      // One run writes each file once: --histogram h.dat beside --plot h.png would be replaced by
      // the plot's data (or refused half-way, after measuring).
      std::error_code a, b;
      if (!o.histogram_csv.empty() &&
          fs::weakly_canonical(file, a) == fs::weakly_canonical(fs::path(o.histogram_csv), b))
        return invalid_argument("--histogram " + o.histogram_csv + " is a file --plot " + o.plot_png +
                                " writes too (" + file.filename().string() + "); name another");
    }
  }

  const KernelPreemption kernel = read_kernel_preemption();
  const std::vector<int> cpus = w.cpus.empty() ? allowed_cpus() : w.cpus;
  spdlog::info("rt-check: {} s at {} us intervals on CPU{} {} ({}), SCHED_FIFO priority {} requested{}",
               w.duration_s, w.interval_us, cpus.size() > 1 ? "s" : "", cpus_text(cpus), cpus_from, w.priority,
               w.load_note.empty() ? "" : "; load: " + w.load_note);

  std::unique_ptr<ProgressBar> bar;
  if (w.duration_s >= 2) {
    bar = std::make_unique<ProgressBar>("rt-check");
    w.progress = [&bar](double f) { bar->update(f); };
  }
  g_stop.store(false);
  w.stop = &g_stop;
  struct sigaction action {}, old_int{}, old_term{};
  action.sa_handler = on_rt_check_interrupt;
  sigaction(SIGINT, &action, &old_int);
  sigaction(SIGTERM, &action, &old_term);
  auto measured = measure_wakeup_latency(w);
  sigaction(SIGINT, &old_int, nullptr);
  sigaction(SIGTERM, &old_term, nullptr);
  if (!measured.ok()) {
    if (o.require_rt) return measured.status().with_context("rt-check --require-rt");
    return measured.status();
  }
  if (bar) bar->finish();
  const WakeupLatencyReport& r = *measured;

  const double fraction = 100.0 * r.max_us() * 1e-3 / loop.period_ms;
  int worst_cpu = -1;
  for (const auto& c : r.cpus)
    if (c.samples > 0 && (worst_cpu < 0 || c.max_us >= r.max_us())) worst_cpu = c.cpu;
  char verdict[1024];
  std::snprintf(verdict, sizeof verdict,
                "max %.0f us (CPU %d) = %.2f %% of the %g ms cycle; %lld of %lld wake-ups over the %.0f us budget; "
                "%s; %s",
                r.max_us(), worst_cpu, fraction, loop.period_ms, static_cast<long long>(r.over_budget()),
                static_cast<long long>(r.samples()), w.budget_us.value_or(0),
                r.fifo() && r.memory_locked ? ("SCHED_FIFO " + std::to_string(r.priority) + " and mlockall in effect").c_str()
                : r.fifo()                  ? ("SCHED_FIFO " + std::to_string(r.priority) + " in effect, memory NOT locked").c_str()
                                            : "NOT real-time (SCHED_FIFO not in effect): not the latency a real-time loop would see",
                kernel.summary().c_str());

  if (!o.histogram_csv.empty())
    LFTRACK_RETURN_IF_ERROR(write_output_file(o.histogram_csv, histogram_csv(r), o.overwrite));
  if (!o.plot_png.empty()) LFTRACK_RETURN_IF_ERROR(draw_histogram_plot(r, kernel, o.plot_png, o.overwrite));

  if (o.json) {
    nlohmann::json j = to_json(r);
    j["scene"] = scene->source;
    j["cycle_period_ms"] = loop.period_ms;
    j["max_fraction_of_cycle_percent"] = fraction;
    j["budget_from"] = budget_from;
    j["cpus_from"] = cpus_from;
    j["kernel"] = {{"release", kernel.release},
                   {"version", kernel.version},
                   {"preempt_rt", kernel.preempt_rt},
                   {"model", kernel.model},
                   {"rt_runtime_us", kernel.rt_runtime_us},
                   {"rt_period_us", kernel.rt_period_us}};
    j["verdict"] = verdict;
    if (!o.histogram_csv.empty()) j["histogram_csv"] = o.histogram_csv;
    if (!o.plot_png.empty()) j["plot"] = o.plot_png;
    std::printf("%s\n", j.dump(2).c_str());
    return {};
  }
  std::printf("scene      %s (%s): cycle %g ms\n", scene->source.c_str(), scene->name.c_str(), loop.period_ms);
  std::printf("kernel     %s %s: %s", kernel.release.c_str(), kernel.version.c_str(), kernel.summary().c_str());
  if (kernel.rt_runtime_us >= 0)
    std::printf("; RT throttling %ld of every %ld us", kernel.rt_runtime_us, kernel.rt_period_us);
  std::printf("\n");
  std::printf("measured   %.1f s (%s), %g us intervals, SCHED_FIFO %d requested on CPU%s %s (%s)%s\n", r.elapsed_s,
              r.stopped_early ? "stopped early" : "as planned", r.interval_us, r.priority, cpus.size() > 1 ? "s" : "",
              cpus_text(cpus).c_str(),
              cpus_from.c_str(), r.load_note.empty() ? "" : ("; load: " + r.load_note).c_str());
  std::printf("in effect  %s\n", r.in_effect().c_str());
  std::printf("budget     %.0f us (%s)\n", w.budget_us.value_or(0), budget_from.c_str());
  for (const auto& c : r.cpus)
    for (const auto& warning : c.warnings) std::printf("warning    CPU %d: %s\n", c.cpu, warning.c_str());
  std::printf("\n");
  print_table(r);
  std::printf("\nverdict: %s\n", verdict);
  if (!o.histogram_csv.empty()) std::printf("histogram: %s\n", o.histogram_csv.c_str());
  if (!o.plot_png.empty()) std::printf("plot: %s\n", o.plot_png.c_str());
  return {};
}

}  // namespace

Command add_rt_check_command(CLI::App* parent) {
  auto* app = parent->add_subcommand(
      "rt-check", "Measure this host's wake-up latency at the scene's SCHED_FIFO priority and CPUs (like cyclictest)");
  auto o = std::make_shared<RtCheckOptions>();
  app->add_option("--scene", o->scene, "Scene file, or builtin:phantom (priority, CPUs, cycle period)")
      ->capture_default_str();
  app->add_option("--duration", o->duration_s, "Seconds to measure (more than 0, at most 3600)")
      ->check(finite_in(0, 3600, true))
      ->capture_default_str();
  app->add_option("--interval-us", o->interval_us, "Wake-up interval in us (50 to 1000000)")
      ->check(finite_in(50, 1e6))
      ->capture_default_str();
  app->add_option("--priority", o->priority, "SCHED_FIFO priority 1..99 (default: the scene's loop.realtime.priority)")
      ->check(CLI::Range(1, 99));
  app->add_option("--cpus", o->cpus,
                  "CPUs to measure, one thread each, e.g. 0,2-3 (default: the scene's loop.realtime.cpus, else every "
                  "CPU this process may use)")
      ->check(cpu_list());
  app->add_option("--budget-us", o->budget_us,
                  "Count wake-ups later than this, 0 to 3600 s in us (default: the cycle's slack, period - "
                  "acquire_timeout - registration_budget)")
      ->check(finite_in(0, 3.6e9));
  app->add_option("--histogram-max-us", o->histogram_max_us, "Histogram range in 1 us bins, 1 to 1000000 (later: overflow)")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  app->add_option("--load-note", o->load_note, "What else ran during the measurement (echoed in the report)");
  app->add_option("--histogram", o->histogram_csv,
                  "Write the per-CPU histograms (1 us bins) to this CSV (an existing file only with --overwrite)");
  app->add_option("--plot", o->plot_png,
                  "Draw a log-scale latency histogram per CPU to this PNG with gnuplot, beside it its .dat and .gp "
                  "(existing files only with --overwrite)");
  app->add_flag("--overwrite", o->overwrite, "Replace existing --histogram and --plot files");
  app->add_flag("--json", o->json, "Print the report as JSON");
  app->add_flag("--require-rt", o->require_rt,
                "Refuse to measure (exit 1) unless mlockall, SCHED_FIFO and the pinning all succeed");
  return [o] { return run_rt_check(*o); };
}

}  // namespace lftrack::cli
