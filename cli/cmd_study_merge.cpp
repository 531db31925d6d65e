// `lftrack study merge`: joins the shards of any sharded study (trade, capture range, realism),
// per scene and, with several scenes, pooled; writes what the unsharded study would have.

#include <cstdio>
#include <fstream>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "cli_commands.hpp"
#include "lftrack/studies/capture_range_study.hpp"
#include "lftrack/studies/realism_study.hpp"
#include "lftrack/studies/slurm_job_array.hpp"
#include "lftrack/studies/trade_study.hpp"

namespace lftrack::cli {

using studies::CaptureRangeReport;
using studies::folder_safe_name;
using studies::merge_capture_range_shards;
using studies::merge_realism_shards;
using studies::merge_trade_shards;
using studies::pool_capture_range_reports;
using studies::pool_realism_reports;
using studies::pool_trade_studies;
using studies::read_capture_range_shard;
using studies::read_realism_shard;
using studies::read_trade_shard;
using studies::RealismReport;
using studies::TradeStudy;
using studies::write_capture_range_outputs;
using studies::write_realism_outputs;
using studies::write_trade_outputs;
namespace {

struct MergeCliOptions {
  std::string out_dir;
  std::vector<std::string> shards;
};

// Which study a shard folder holds ("trade" for folders written before study.json named it).
Result<std::string> study_kind(const std::string& dir) {
  std::ifstream in(std::filesystem::path(dir) / "study.json");
  if (!in) return not_found(dir + "/study.json: no such file (not a study's shard?)");
  try {
    return nlohmann::json::parse(in).value("study", std::string("trade"));
  } catch (const std::exception& e) {
    return corrupt_data(dir + "/study.json: " + e.what());
  }
}

// Every shard folder read with `reader`; the first that does not read stops it.
template <typename Study, typename Reader>
Result<std::vector<Study>> read_shards(const std::vector<std::string>& dirs, Reader reader) {
  std::vector<Study> shards;
  for (const auto& dir : dirs) {
    auto s = reader(dir);
    if (!s.ok()) return s.status();
    shards.push_back(std::move(s).value());
  }
  return shards;
}

template <typename Study>
using Merger = std::function<Result<Study>(const std::vector<Study>&)>;

// Shards grouped by scene (in the order first seen), each group merged; `name_of` names a study's scene.
template <typename Study>
Result<std::vector<Study>> merge_per_scene(const std::vector<Study>& shards, const Merger<Study>& merge,
                                           const std::function<std::string(const Study&)>& name_of) {
  std::vector<std::string> order;
  std::map<std::string, std::vector<Study>> groups;
  for (const Study& s : shards) {
    if (!groups.count(name_of(s))) order.push_back(name_of(s));
    groups[name_of(s)].push_back(s);
  }
  std::vector<Study> merged;
  for (const std::string& name : order) {
    auto m = merge(groups[name]);
    if (!m.ok()) return m.status().with_context("scene '" + name + "'");
    merged.push_back(std::move(m).value());
  }
  return merged;
}

// Several scenes' folders under the merge's --out: one each, none called "pooled".
template <typename Study>
Status check_scene_folders(const std::vector<Study>& merged) {
  std::set<std::string> folders{"pooled"};
  for (const Study& s : merged)
    if (!folders.insert(folder_safe_name(s.scene)).second)
      return failed_precondition("merge: scene '" + s.scene + "' would be written to the folder '" +
                                 folder_safe_name(s.scene) + "', which another scene or the pooled study takes; "
                                 "rename the scene");
  return {};
}

Status merge_trade(const std::vector<std::string>& dirs, const std::filesystem::path& out) {
  auto read = read_shards<TradeStudy>(dirs, read_trade_shard);
  if (!read.ok()) return read.status();
  const std::vector<TradeStudy>& shards = *read;
  auto merged = merge_per_scene<TradeStudy>(shards, merge_trade_shards, [](const TradeStudy& s) { return s.scene; });
  if (!merged.ok()) return merged.status();
  if (merged->size() == 1) {
    LFTRACK_RETURN_IF_ERROR(write_trade_outputs(merged->front(), out));
    print_trade_front(merged->front());
    std::printf("merged %zu shards, %zu points; wrote %s/{points.csv,runs.csv,summary.md,summary.json,"
                "tre_vs_time.png,memory_vs_fidelity.png,verdict.png}\n",
                shards.size(), merged->front().results.size(), out.c_str());
    return {};
  }
  LFTRACK_RETURN_IF_ERROR(check_scene_folders(*merged));
  for (const TradeStudy& s : *merged) LFTRACK_RETURN_IF_ERROR(write_trade_outputs(s, out / folder_safe_name(s.scene)));
  std::vector<std::string> left_out;
  auto pooled = pool_trade_studies(*merged, &left_out);
  if (!pooled.ok()) return pooled.status();
  LFTRACK_RETURN_IF_ERROR(write_trade_outputs(*pooled, out / "pooled"));
  std::printf("Pooled over %zu scenes (%d problems per point):\n", merged->size(), pooled->problems);
  print_trade_front(*pooled);
  if (!left_out.empty()) {
    std::string ids;
    for (const auto& id : left_out) ids += (ids.empty() ? "" : ", ") + id;
    std::printf("left out of the pooled study (not in every scene): %s\n", ids.c_str());
  }
  std::printf("merged %zu shards of %zu scenes; wrote %s/<scene>/ per scene and %s/pooled/\n", shards.size(),
              merged->size(), out.c_str(), out.c_str());
  return {};
}

Status merge_capture_range(const std::vector<std::string>& dirs, const std::filesystem::path& out) {
  auto read = read_shards<CaptureRangeReport>(dirs, read_capture_range_shard);
  if (!read.ok()) return read.status();
  const std::vector<CaptureRangeReport>& shards = *read;
  auto merged = merge_per_scene<CaptureRangeReport>(shards, merge_capture_range_shards,
                                                    [](const CaptureRangeReport& s) { return s.scene; });
  if (!merged.ok()) return merged.status();
  if (merged->size() == 1) {
    LFTRACK_RETURN_IF_ERROR(write_capture_range_outputs(merged->front(), out));
    std::printf("merged %zu shards, %zu runs; wrote %s/{runs.csv,summary.json,capture_range.png,verdict.png}\n", shards.size(),
                merged->front().runs.size(), out.c_str());
    return {};
  }
  LFTRACK_RETURN_IF_ERROR(check_scene_folders(*merged));
  for (const CaptureRangeReport& s : *merged)
    LFTRACK_RETURN_IF_ERROR(write_capture_range_outputs(s, out / folder_safe_name(s.scene)));
  auto pooled = pool_capture_range_reports(*merged);
  if (!pooled.ok()) return pooled.status();
  LFTRACK_RETURN_IF_ERROR(write_capture_range_outputs(*pooled, out / "pooled"));
  std::printf("merged %zu shards of %zu scenes; wrote %s/<scene>/ per scene and %s/pooled/\n", shards.size(),
              merged->size(), out.c_str(), out.c_str());
  return {};
}

Status merge_realism(const std::vector<std::string>& dirs, const std::filesystem::path& out) {
  auto read = read_shards<RealismReport>(dirs, read_realism_shard);
  if (!read.ok()) return read.status();
  const std::vector<RealismReport>& shards = *read;
  auto merged = merge_per_scene<RealismReport>(shards, merge_realism_shards,
                                               [](const RealismReport& s) { return s.scene; });
  if (!merged.ok()) return merged.status();
  if (merged->size() == 1) {
    LFTRACK_RETURN_IF_ERROR(write_realism_outputs(merged->front(), out));
    print_realism_table(merged->front());
    std::printf("merged %zu shards; wrote %s/{summary.json,realism.csv,realism_tre.png,realism_rates.png} and a capture-range study per "
                "factor set\n",
                shards.size(), out.c_str());
    return {};
  }
  LFTRACK_RETURN_IF_ERROR(check_scene_folders(*merged));
  for (const RealismReport& s : *merged)
    LFTRACK_RETURN_IF_ERROR(write_realism_outputs(s, out / folder_safe_name(s.scene)));
  auto pooled = pool_realism_reports(*merged);
  if (!pooled.ok()) return pooled.status();
  LFTRACK_RETURN_IF_ERROR(write_realism_outputs(*pooled, out / "pooled"));
  std::printf("Pooled over %zu scenes:\n", merged->size());
  print_realism_table(*pooled);
  std::printf("merged %zu shards of %zu scenes; wrote %s/<scene>/ per scene and %s/pooled/\n", shards.size(),
              merged->size(), out.c_str(), out.c_str());
  return {};
}

Status run_merge(const MergeCliOptions& o) {
  // The output is never one of the shards (a merge there would overwrite that shard's result).
  std::error_code ec;
  const auto out = std::filesystem::weakly_canonical(o.out_dir, ec);
  for (const auto& dir : o.shards) {
    const auto shard = std::filesystem::weakly_canonical(dir, ec);
    const auto rel = out.lexically_relative(shard);
    if (out == shard || (!rel.empty() && *rel.begin() != ".."))
      return invalid_argument("merge: --out " + o.out_dir + " is, or is inside, the shard folder " + dir +
                              "; choose a folder of its own");
  }
  // Nothing is replaced: the merge writes into a new or empty folder.
  if (std::filesystem::exists(o.out_dir, ec) && !std::filesystem::is_empty(o.out_dir, ec))
    return failed_precondition("merge: --out " + o.out_dir +
                               " is not empty (an earlier merge?); a merge writes into a new or empty folder");
  std::string kind;
  for (const auto& dir : o.shards) {
    auto k = study_kind(dir);
    if (!k.ok()) return k.status();
    if (!kind.empty() && *k != kind)
      return failed_precondition("merge: " + dir + " holds a " + *k + " study, the others a " + kind + " study");
    kind = *k;
  }
  if (kind == "trade") return merge_trade(o.shards, o.out_dir);
  if (kind == "capture-range") return merge_capture_range(o.shards, o.out_dir);
  if (kind == "realism") return merge_realism(o.shards, o.out_dir);
  return unsupported("merge: unknown study '" + kind + "'");
}

}  // namespace

Command add_study_merge_command(CLI::App* parent) {
  auto* app =
      parent->add_subcommand("merge", "Join the shards of a trade, capture-range or realism study (several scenes: per "
                                      "scene and pooled) and write its plots and summary");
  auto o = std::make_shared<MergeCliOptions>();
  app->add_option("--out", o->out_dir, "Output folder, new or empty (nothing in it is replaced)")
      ->required()
      ->check(not_empty());
  app->add_option("shards", o->shards, "The shards' output folders")
      ->required()
      ->check(CLI::ExistingDirectory);
  return [o]() { return run_merge(*o); };
}

}  // namespace lftrack::cli
