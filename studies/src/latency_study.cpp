#include "lftrack/studies/latency_study.hpp"

#include <fmt/format.h>

#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>

#include "lftrack/records/journal_reader.hpp"
#include "lftrack/studies/plot.hpp"
#include "quantile.hpp"

namespace lftrack::host {
namespace {

namespace fs = std::filesystem;

constexpr const char* kOutputs[] = {"chain.csv", "summary.json", "latency_chain.png", "latency_chain.dat",
                                    "latency_chain.gp"};

LinkLatency exact(const std::vector<double>& ms) {
  LinkLatency l;
  l.p50_ms = quantile(ms, 0.50);
  l.p95_ms = quantile(ms, 0.95);
  l.p99_ms = quantile(ms, 0.99);
  for (double v : ms) l.max_ms = std::max(l.max_ms, v);
  return l;
}

nlohmann::json link_json(const LinkLatency& l) {
  return {{"p50", l.p50_ms}, {"p95", l.p95_ms}, {"p99", l.p99_ms}, {"max", l.max_ms}};
}

// Histograms on log-spaced bins, ten a decade from 1 us to 1 s: each link's share of the
// commands (%) per bin, empty bins left as gaps.
LinePlot histogram_plot(const LatencyStudy& s) {
  constexpr int kPerDecade = 10, kDecades = 6;
  constexpr double kFirstEdgeMs = 1e-3;
  LinePlot plot;
  plot.title =
      fmt::format("latency chain, {} commands (exposure to acknowledgement p50 {:.2f} ms, p99 {:.2f} ms)",
                  s.report.commands, s.report.total.p50_ms, s.report.total.p99_ms);
  plot.x_label = "ms (log)";
  plot.y_label = "commands in the bin (%)";
  plot.log_x = true;
  plot.key_position = "top right";
  const int bins = kPerDecade * kDecades;
  for (int b = 0; b < bins; ++b) plot.x.push_back(kFirstEdgeMs * std::pow(10.0, (b + 0.5) / kPerDecade));
  auto series = [&](const std::string& name, const auto& value_of) {
    PlotSeries p;
    p.name = name;
    std::vector<double> counts(std::size_t(bins), 0);
    for (const auto& chain : s.chains) {
      const double v = std::max(value_of(chain), kFirstEdgeMs);
      const int b =
          std::min(bins - 1, static_cast<int>(std::floor(std::log10(v / kFirstEdgeMs) * kPerDecade)));
      counts[std::size_t(b)] += 1;
    }
    for (double c : counts) p.y.push_back(c > 0 ? 100.0 * c / double(s.chains.size()) : NAN);
    plot.series.push_back(std::move(p));
  };
  for (int i = 0; i < kLatencyLinks; ++i)
    series(to_string(static_cast<LatencyLink>(i)), [i](const auto& chain) { return chain[std::size_t(i)]; });
  series("exposure to acknowledgement", [](const auto& chain) {
    double total = 0;
    for (double v : chain) total += v;
    return total;
  });
  return plot;
}

}  // namespace

Result<LatencyStudy> run_latency_study(const std::vector<fs::path>& journals) {
  if (journals.empty()) return invalid_argument("no journal given");
  LatencyStudy s;
  int read = 0;
  Status last_error;
  for (const fs::path& file : journals) {
    auto contents = read_journal(file);
    if (!contents.ok()) {
      s.notes.push_back(contents.status().message());
      last_error = contents.status();
      continue;
    }
    ++read;
    s.journals.push_back(file.string());
    if (contents->damaged())
      s.notes.push_back(fmt::format("{}: damaged ({} bad spans, {} gaps); its {} valid records are used",
                                    file.string(), contents->bad_spans.size(), contents->gaps.size(),
                                    contents->records.size()));
    std::int64_t with_chain = 0, commands = 0;
    for (const JournalRecord& r : contents->records) {
      ++s.records;
      if (r.command_sent == 0) continue;
      ++commands;
      if (auto links = latency_links_ms(r)) {
        s.chains.push_back(*links);
        ++with_chain;
      }
    }
    s.commands += commands;
    if (commands > 0 && with_chain == 0)
      s.notes.push_back(fmt::format(
          "{}: {} commands, none with a latency chain ({}): the chain is journaled on the real clock, from "
          "journal format 5 on",
          file.string(), commands,
          contents->format_version < 5 ? fmt::format("format {}", contents->format_version)
                                       : std::string("the simulated clock")));
    else if (with_chain < commands)
      s.notes.push_back(fmt::format("{}: {} of {} commands have no whole chain (a link not reached)",
                                    file.string(), commands - with_chain, commands));
  }
  if (read == 0) return last_error;
  s.report.commands = static_cast<std::int64_t>(s.chains.size());
  std::vector<double> values(s.chains.size());
  for (int i = 0; i <= kLatencyLinks; ++i) {
    for (std::size_t c = 0; c < s.chains.size(); ++c) {
      double v = 0;
      if (i < kLatencyLinks) {
        v = s.chains[c][std::size_t(i)];
      } else {
        for (double link : s.chains[c]) v += link;
      }
      values[c] = v;
    }
    (i < kLatencyLinks ? s.report.links[std::size_t(i)] : s.report.total) = exact(values);
  }
  return s;
}

Status write_latency_study(const LatencyStudy& s, const fs::path& out_dir) {
  if (s.chains.empty())
    return failed_precondition("no command with a latency chain in the journals: nothing to plot" +
                               (s.notes.empty() ? std::string() : " (" + s.notes.front() + ")"));
  std::error_code ec;
  for (const char* name : kOutputs)
    if (fs::exists(out_dir / name, ec) || fs::is_symlink(out_dir / name, ec))
      return failed_precondition((out_dir / name).string() +
                                 " exists: an earlier study's; give another --out (nothing was written)");
  fs::create_directories(out_dir, ec);
  if (ec) return io_error(out_dir.string() + ": cannot create: " + ec.message());
  {
    std::ofstream csv(out_dir / "chain.csv");
    if (!csv) return io_error((out_dir / "chain.csv").string() + ": cannot write");
    csv << "command";
    for (int i = 0; i < kLatencyLinks; ++i) csv << ',' << key_of(static_cast<LatencyLink>(i)) << "_ms";
    csv << ",total_ms\n";
    for (std::size_t c = 0; c < s.chains.size(); ++c) {
      double total = 0;
      csv << c;
      for (double v : s.chains[c]) {
        csv << ',' << fmt::format("{:.4f}", v);
        total += v;
      }
      csv << ',' << fmt::format("{:.4f}", total) << '\n';
    }
    csv.flush();
    if (!csv) return io_error((out_dir / "chain.csv").string() + ": write failed (disk full?)");
  }
  nlohmann::json j;
  j["journals"] = s.journals;
  j["records"] = s.records;
  j["commands"] = s.commands;
  j["commands_with_chain"] = s.report.commands;
  nlohmann::json links;
  for (int i = 0; i < kLatencyLinks; ++i)
    links[key_of(static_cast<LatencyLink>(i))] = link_json(s.report.links[std::size_t(i)]);
  j["links_ms"] = links;
  j["exposure_to_acknowledgement_ms"] = link_json(s.report.total);
  j["notes"] = s.notes;
  {
    std::ofstream out(out_dir / "summary.json");
    out << j.dump(2) << '\n';
    out.flush();
    if (!out) return io_error((out_dir / "summary.json").string() + ": write failed");
  }
  auto drawn = draw_line_plot(histogram_plot(s), out_dir / "latency_chain.png");
  if (!drawn.ok()) return drawn.status();
  return {};
}

}  // namespace lftrack::host
