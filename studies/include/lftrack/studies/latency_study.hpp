#pragma once
// `lftrack study latency`: the latency chain of a run's corrections, link by link, from its
// journals (latency_chain.hpp names the links): every command's links, their quantiles, and a
// histogram per link that a person reads at a glance.

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/loop/latency_chain.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::studies {

// One command's chain and where it came from.
struct CommandChain {
  int journal = 0;          // index into LatencyStudy::journals
  std::uint64_t cycle = 0;  // the journal's cycle counter
  std::array<double, loop::kLatencyLinks> links_ms{};
  double total_ms() const;
};

struct LatencyStudy {
  std::vector<std::string> journals;
  std::int64_t records = 0;   // cycles read (a repeated cycle once)
  std::int64_t commands = 0;  // commands sent
  std::vector<CommandChain> chains;  // in file order
  // Quantiles by nearest rank (the smallest value with at least q of the commands at or below
  // it), as the loop's summary takes them from its 0.01 ms bins: the two agree within a bin.
  loop::LatencyChainReport report;
  std::vector<std::string> notes;  // damage, repeated cycles, commands without a whole chain
};

// Reads every journal. Refused: no journal, one that cannot be read, the same file twice, and a
// journal whose commands have no chain (the simulated clock, a format before 5): a study of
// several runs would otherwise quietly be a study of fewer. A damaged journal's valid records are
// used, with a note (journal export's exit status judges the damage); a repeated cycle is counted
// once.
Result<LatencyStudy> run_latency_study(const std::vector<std::filesystem::path>& journals);

// `out_dir`/chain.csv (one row per command: journal, cycle, links, total), summary.json,
// latency_chain.png (a histogram per link and the total; its .dat and .gp beside it). Refuses to
// replace a file of those names already there. Returns whether the PNG was drawn (gnuplot
// missing: the data and script are written, the PNG not).
Result<bool> write_latency_study(const LatencyStudy& study, const std::filesystem::path& out_dir);

}  // namespace lftrack::studies
