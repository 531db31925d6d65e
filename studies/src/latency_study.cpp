#include "lftrack/studies/latency_study.hpp"

#include <sys/stat.h>

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>

#include "lftrack/records/journal_reader.hpp"
#include "lftrack/records/loop_json.hpp"
#include "lftrack/studies/plot.hpp"
#include "study_outputs.hpp"

namespace lftrack::studies {

using loop::JournalRecord;
using loop::kLatencyLinks;
using loop::latency_links_ms;
using loop::LatencyLink;
using loop::LinkLatency;
using loop::NoChain;
using loop::total_ms;

using records::JournalCycleRepeat;
using records::read_journal;
using records::to_json;
namespace {

namespace fs = std::filesystem;

constexpr const char* kOutputs[] = {"chain.csv", "summary.json", "latency_chain.png", "latency_chain.dat",
                                    "latency_chain.gp"};

// Nearest rank: the smallest value with at least q of `sorted` at or below it.
double nearest_rank(const std::vector<double>& sorted, double q) {
  if (sorted.empty()) return 0;
  const double rank = std::ceil(std::clamp(q, 0.0, 1.0) * double(sorted.size()));
  return sorted[std::size_t(std::clamp(rank, 1.0, double(sorted.size()))) - 1];
}

LinkLatency quantiles(std::vector<double> ms) {
  std::sort(ms.begin(), ms.end());
  LinkLatency l;
  l.p50_ms = nearest_rank(ms, 0.50);
  l.p95_ms = nearest_rank(ms, 0.95);
  l.p99_ms = nearest_rank(ms, 0.99);
  l.max_ms = ms.empty() ? 0 : ms.back();
  return l;
}

// Histograms on log-spaced bins, ten a decade from 0.1 us to 1 s (the write link is well under a
// microsecond; shorter values, zero included, count in the first bin, longer in the last): each
// link's share of the commands (%) per bin, zero between a link's first and last filled bins and
// left out beyond them.
LinePlot histogram_plot(const LatencyStudy& s) {
  constexpr int kPerDecade = 10, kDecades = 7;
  constexpr double kFirstEdgeMs = 1e-4;
  const std::size_t n = s.chains.size();
  LinePlot plot;
  plot.title =
      fmt::format("latency chain, {} command{} (exposure to acknowledgement p50 {:.2f} ms, p99 {:.2f} ms)", n,
                  n == 1 ? "" : "s", s.report.total.p50_ms, s.report.total.p99_ms);
  plot.x_label = "ms (log; bins of a tenth of a decade)";
  plot.y_label = "commands in the bin (%)";
  plot.log_x = true;
  plot.key_position = "top right";
  const int bins = kPerDecade * kDecades;
  for (int b = 0; b < bins; ++b) plot.x.push_back(kFirstEdgeMs * std::pow(10.0, (b + 0.5) / kPerDecade));
  double highest = 0;
  auto series = [&](const std::string& name, const auto& value_of) {
    PlotSeries p;
    p.name = name;
    std::vector<double> counts(std::size_t(bins), 0);
    for (const CommandChain& chain : s.chains) {
      const double v = std::max(value_of(chain), kFirstEdgeMs);
      const int b =
          std::min(bins - 1, static_cast<int>(std::floor(std::log10(v / kFirstEdgeMs) * kPerDecade)));
      counts[std::size_t(b)] += 1;
    }
    const auto first = std::find_if(counts.begin(), counts.end(), [](double c) { return c > 0; });
    const auto last = std::find_if(counts.rbegin(), counts.rend(), [](double c) { return c > 0; }).base();
    for (auto it = counts.begin(); it != counts.end(); ++it) {
      const bool inside = it >= first && it < last;
      p.y.push_back(inside ? 100.0 * *it / double(n) : NAN);
      if (inside) highest = std::max(highest, p.y.back());
    }
    plot.series.push_back(std::move(p));
  };
  for (int i = 0; i < kLatencyLinks; ++i)
    series(to_string(static_cast<LatencyLink>(i)),
           [i](const CommandChain& c) { return c.links_ms[std::size_t(i)]; });
  series("exposure to acknowledgement", [](const CommandChain& c) { return c.total_ms(); });
  plot.y_min = 0;
  plot.y_max = std::min(105.0, 1.1 * highest + 1);
  return plot;
}

}  // namespace

double CommandChain::total_ms() const {
  return loop::total_ms(links_ms);
}

Result<LatencyStudy> run_latency_study(const std::vector<fs::path>& journals) {
  if (journals.empty()) return invalid_argument("no journal given");
  LatencyStudy s;
  std::set<std::string> seen;
  for (const fs::path& file : journals) {
    // The same file by any path (a link too): its device and inode.
    struct stat st {};
    const std::string key =
        ::stat(file.c_str(), &st) == 0 ? fmt::format("{}:{}", st.st_dev, st.st_ino) : file.string();
    if (!seen.insert(key).second)
      return invalid_argument(file.string() +
                              ": given twice (the same file by another path or link): each journal once");
    auto contents = read_journal(file);
    if (!contents.ok()) return contents.status();
    const int index = static_cast<int>(s.journals.size());
    s.journals.push_back(file.string());
    if (contents->damaged())
      s.notes.push_back(fmt::format(
          "{}: damaged ({} bad spans, {} gaps, {} repeated cycles; journal export names them); its {} valid "
          "records are used, a repeated cycle once",
          file.string(), contents->bad_spans.size(), contents->gaps.size(), contents->repeats.size(),
          contents->records.size()));
    std::set<std::size_t> repeated;  // record indices of repeated cycles: counted once
    for (const JournalCycleRepeat& r : contents->repeats) repeated.insert(r.record_index);
    std::int64_t with_chain = 0, commands = 0;
    std::int64_t without[4] = {};
    for (std::size_t i = 0; i < contents->records.size(); ++i) {
      if (repeated.count(i) > 0) continue;
      const JournalRecord& r = contents->records[i];
      ++s.records;
      if (r.command_sent == 0) continue;
      ++commands;
      NoChain why = NoChain::kNotTimed;
      if (auto links = latency_links_ms(r, &why)) {
        s.chains.push_back({index, r.cycle, *links});
        ++with_chain;
      } else {
        ++without[static_cast<int>(why)];
      }
    }
    s.commands += commands;
    if (commands == 0) {
      s.notes.push_back(file.string() + ": no command was sent (" + std::to_string(contents->records.size()) +
                        " records)");
    } else if (with_chain == 0) {
      return failed_precondition(fmt::format(
          "{}: {} commands, none with a latency chain ({}): the chain is journaled on the real clock, from "
          "journal format 5 on; leave this journal out",
          file.string(), commands,
          contents->format_version < 5 ? fmt::format("journal format {}", contents->format_version)
          : without[static_cast<int>(NoChain::kNotTimed)] == commands ? std::string("the simulated clock")
                                                                      : std::string("every chain damaged")));
    } else {
      for (int why = 0; why < 4; ++why)
        if (without[why] > 0)
          s.notes.push_back(fmt::format("{}: {} of {} commands left out: {}", file.string(), without[why],
                                        commands, to_string(static_cast<NoChain>(why))));
    }
  }
  s.report.commands = static_cast<std::int64_t>(s.chains.size());
  std::vector<double> values(s.chains.size());
  for (int i = 0; i < kLatencyLinks; ++i) {
    for (std::size_t c = 0; c < s.chains.size(); ++c) values[c] = s.chains[c].links_ms[std::size_t(i)];
    s.report.links[std::size_t(i)] = quantiles(values);
  }
  for (std::size_t c = 0; c < s.chains.size(); ++c) values[c] = s.chains[c].total_ms();
  s.report.total = quantiles(values);
  return s;
}

Result<bool> write_latency_study(const LatencyStudy& s, const fs::path& out_dir) {
  if (s.chains.empty())
    return failed_precondition("no command with a latency chain in the journals: nothing to plot" +
                               (s.notes.empty() ? std::string() : " (" + s.notes.front() + ")"));
  LFTRACK_RETURN_IF_ERROR(refuse_existing_outputs(out_dir, kOutputs));
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  if (ec) return io_error(out_dir.string() + ": cannot create: " + ec.message());
  {
    std::ofstream csv(out_dir / "chain.csv");
    if (!csv) return io_error((out_dir / "chain.csv").string() + ": cannot write: " + std::strerror(errno));
    csv << "journal,cycle";
    for (int i = 0; i < kLatencyLinks; ++i) csv << ',' << key_of(static_cast<LatencyLink>(i)) << "_ms";
    csv << ",total_ms\n";
    for (const CommandChain& c : s.chains) {
      csv << c.journal << ',' << c.cycle;
      for (double v : c.links_ms) csv << ',' << fmt::format("{:.6f}", v);  // ns resolution
      csv << ',' << fmt::format("{:.6f}", c.total_ms()) << '\n';
    }
    csv.flush();
    if (!csv) return io_error((out_dir / "chain.csv").string() + ": write failed (disk full?)");
  }
  nlohmann::json j;
  j["journals"] = s.journals;  // chain.csv's `journal` column indexes this list
  j["records"] = s.records;
  j["commands"] = s.commands;
  j["commands_with_chain"] = s.report.commands;
  j["quantiles"] = "nearest rank";
  nlohmann::json links;
  for (int i = 0; i < kLatencyLinks; ++i)
    links[key_of(static_cast<LatencyLink>(i))] = to_json(s.report.links[std::size_t(i)]);
  j["links_ms"] = links;
  j["exposure_to_acknowledgement_ms"] = to_json(s.report.total);
  j["notes"] = s.notes;
  {
    std::ofstream out(out_dir / "summary.json");
    if (!out)
      return io_error((out_dir / "summary.json").string() + ": cannot write: " + std::strerror(errno));
    out << j.dump(2) << '\n';
    out.flush();
    if (!out) return io_error((out_dir / "summary.json").string() + ": write failed (disk full?)");
  }
  return draw_line_plot(histogram_plot(s), out_dir / "latency_chain.png");
}

}  // namespace lftrack::studies
