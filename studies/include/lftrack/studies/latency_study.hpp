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

namespace lftrack::host {

struct LatencyStudy {
  std::vector<std::string> journals;
  std::int64_t records = 0;   // cycles read
  std::int64_t commands = 0;  // commands sent
  // One per command with a whole chain (real clock, journal format 5 on), in ms, in file order.
  std::vector<std::array<double, kLatencyLinks>> chains;
  LatencyChainReport report;       // exact quantiles of `chains` (not binned)
  std::vector<std::string> notes;  // journals without a chain, damage, records left out
};

// Reads every journal (a damaged one's valid records, with a note); an error when none can be
// read. A journal with no chain is a note, not an error: the study says so.
Result<LatencyStudy> run_latency_study(const std::vector<std::filesystem::path>& journals);

// `out_dir`/chain.csv (one row per command), summary.json, latency_chain.png (a histogram per link
// and the total; its .dat and .gp beside it). Refuses to replace files an earlier study wrote
// there: a study's record is not overwritten.
Status write_latency_study(const LatencyStudy& study, const std::filesystem::path& out_dir);

}  // namespace lftrack::host
