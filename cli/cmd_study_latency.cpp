// `lftrack study latency JOURNAL... --out DIR`: the latency chain of a run's corrections, link by
// link, from its journals (latency_study.hpp).

#include <cstdio>
#include <filesystem>
#include <memory>

#include "cli_commands.hpp"
#include "lftrack/studies/latency_study.hpp"

namespace lftrack::cli {

using studies::run_latency_study;
using studies::write_latency_study;

using loop::kLatencyLinks;
using loop::LatencyChainReport;
using loop::LatencyLink;
using loop::LinkLatency;

Command add_study_latency_command(CLI::App* parent) {
  struct Options {
    std::vector<std::string> journals;
    std::string out_dir;
  };
  auto o = std::make_shared<Options>();
  auto* app = parent->add_subcommand("latency",
                                     "The latency chain of a run's corrections from its journals, link by "
                                     "link: exposure to arrival on the host, "
                                     "preprocess, register, gate, write, acknowledge (the real clock; "
                                     "journal format 5 on); a table, a CSV and "
                                     "a histogram per link");
  app->add_option("journals", o->journals, "Journals of real-clock runs (lftrack run or sim --journal)")
      ->required()
      ->check(CLI::ExistingFile);
  app->add_option("--out", o->out_dir,
                  "Folder for chain.csv, summary.json and latency_chain.png (nothing in it is "
                  "replaced)")
      ->required()
      ->check(not_empty());
  return [o, app]() -> Status {
    if (!app->parsed()) return {};
    std::vector<std::filesystem::path> files(o->journals.begin(), o->journals.end());
    auto study = run_latency_study(files);
    if (!study.ok()) return study.status();
    for (const std::string& note : study->notes) std::fprintf(stderr, "note: %s\n", note.c_str());
    const LatencyChainReport& r = study->report;
    if (r.commands == 0)
      return failed_precondition("no command with a latency chain in the journals: nothing to measure");
    std::printf(
        "%lld commands of %lld with a latency chain, from %zu journal(s); quantiles by nearest rank\n",
        static_cast<long long>(r.commands), static_cast<long long>(study->commands), study->journals.size());
    std::printf("%-28s %9s %9s %9s %9s\n", "link (ms)", "p50", "p95", "p99", "max");
    auto row = [](const char* name, const LinkLatency& l) {
      std::printf("%-28s %9.3f %9.3f %9.3f %9.3f\n", name, l.p50_ms, l.p95_ms, l.p99_ms, l.max_ms);
    };
    for (int i = 0; i < kLatencyLinks; ++i)
      row(to_string(static_cast<LatencyLink>(i)), r.links[std::size_t(i)]);
    row("exposure to acknowledgement", r.total);
    auto drawn = write_latency_study(*study, o->out_dir);
    if (!drawn.ok()) return drawn.status();
    std::printf(
        "wrote %s/{chain.csv,summary.json%s}\n", o->out_dir.c_str(),
        *drawn ? ",latency_chain.png" : ",latency_chain.dat,latency_chain.gp; no PNG: gnuplot is missing");
    return {};
  };
}

}  // namespace lftrack::cli
