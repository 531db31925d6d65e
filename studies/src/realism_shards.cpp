// The realism study's shards: their description, reading back, merging and pooling
// (realism_study.hpp). Each factor set's runs are a capture-range shard in DIR/<set>/; this file
// only adds what ties the sets into one realism shard, and reuses the capture-range study's
// checks, merge and pooling per set.

#include <algorithm>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>

#include "lftrack/studies/realism_study.hpp"
#include "lftrack/studies/slurm_job_array.hpp"  // folder_safe_name
#include "lftrack/studies/study_shard.hpp"

namespace lftrack::studies {
namespace {

std::vector<std::string> set_names(const RealismReport& r) {
  std::vector<std::string> names;
  for (const CaptureRangeReport& s : r.studies) names.push_back(s.options.physics_name);
  return names;
}

// What two shards (or two scenes) must share to be one realism study, besides the scene.
nlohmann::json options_json(const RealismReport& r) {
  const RealismOptions& o = r.options;
  return {{"gold_poses", o.per_bin},        {"bins", o.bins},
          {"anatomy_draws", o.anatomy_draws}, {"image_starts_up_to_mm", o.image_max_mm},
          {"hybrid_starts_up_to_mm", o.hybrid_max_mm}, {"seed", o.seed},
          {"renderer", o.renderer},          {"image_method", r.image_method},
          {"hybrid_method", r.hybrid_method}, {"sets", set_names(r)}};
}

std::string shard_name(const RealismReport& r) {
  return "realism shard " + std::to_string(r.options.shard) + "/" + std::to_string(r.options.shards) +
         " of scene '" + r.scene + "'";
}

// The report's factor summaries from its sets' studies.
void summarize(RealismReport* r) {
  r->factors.clear();
  for (const CaptureRangeReport& s : r->studies)
    r->factors.push_back(summarize_realism_factor(r->options, s, r->image_method, r->hybrid_method));
}

}  // namespace

Status write_realism_description(const RealismReport& report, const std::filesystem::path& dir) {
  std::size_t runs = 0;
  for (const CaptureRangeReport& s : report.studies) runs += s.runs.size();
  const nlohmann::json j = {{"study", "realism"},
                            {"scene", report.scene},
                            {"fingerprint", report.fingerprint},
                            {"shard", report.options.shard},
                            {"shards", report.options.shards},
                            {"runs", runs},
                            {"options", options_json(report)}};
  return write_file_atomically(dir / "study.json", j.dump(2) + "\n");
}

Result<RealismReport> read_realism_shard(const std::filesystem::path& dir) {
  RealismReport r;
  RealismOptions& o = r.options;
  std::vector<std::string> sets;
  const auto file = dir / "study.json";
  {
    std::ifstream in(file);
    if (!in) return not_found(file.string() + ": no such file (not a study folder?)");
    try {
      const auto j = nlohmann::json::parse(in);
      if (j.value("study", "") != "realism") return failed_precondition(file.string() + ": not a realism study's shard");
      r.scene = j.at("scene").get<std::string>();
      r.fingerprint = j.at("fingerprint").get<std::string>();
      const auto shard = j.at("shard").get<std::int64_t>();
      const auto shards = j.at("shards").get<std::int64_t>();
      LFTRACK_RETURN_IF_ERROR(check_shard_position(shard, shards, file));
      o.shard = int(shard);
      o.shards = int(shards);
      const auto& opt = j.at("options");
      const auto per_bin = opt.at("gold_poses").get<std::int64_t>();
      const auto bins = opt.at("bins").get<std::int64_t>();
      const auto draws = opt.at("anatomy_draws").get<std::int64_t>();
      if (per_bin < 1 || per_bin > 1000000 || bins < 1 || bins > 32 || draws < 1 || draws > 100000)
        return corrupt_data(file.string() + ": gold_poses, bins or anatomy_draws out of range");
      o.per_bin = int(per_bin);
      o.bins = int(bins);
      o.anatomy_draws = int(draws);
      o.image_max_mm = opt.at("image_starts_up_to_mm").get<double>();
      o.hybrid_max_mm = opt.at("hybrid_starts_up_to_mm").get<double>();
      if (!(o.image_max_mm >= 0 && o.image_max_mm <= 1e3 && o.hybrid_max_mm >= 0 && o.hybrid_max_mm <= 1e3))
        return corrupt_data(file.string() + ": start limits out of range");
      o.seed = opt.at("seed").get<std::uint64_t>();
      o.renderer = opt.at("renderer").get<std::string>();
      r.image_method = opt.at("image_method").get<std::string>();
      r.hybrid_method = opt.at("hybrid_method").get<std::string>();
      sets = opt.at("sets").get<std::vector<std::string>>();
    } catch (const std::exception& e) {
      return corrupt_data(file.string() + ": " + e.what());
    }
  }
  if (sets.empty() || sets.size() > 64) return corrupt_data(file.string() + ": no factor sets, or too many");
  std::set<std::string> seen;
  for (const std::string& set : sets) {
    // A set names a folder inside this one: nothing that climbs out or hides.
    if (folder_safe_name(set) != set || !seen.insert(set).second)
      return corrupt_data(file.string() + ": factor set '" + set + "' is not a folder name, or is listed twice");
    auto study = read_capture_range_shard(dir / set);
    if (!study.ok()) return study.status().with_context("realism shard " + dir.string());
    if (study->options.physics_name != set || study->scene != r.scene || study->fingerprint != r.fingerprint ||
        study->options.shard != o.shard || study->options.shards != o.shards)
      return corrupt_data((dir / set).string() + ": holds another study than " + file.string() + " describes");
    r.studies.push_back(std::move(study).value());
  }
  o.only = sets;
  summarize(&r);
  return r;
}

Status check_realism_shard_complete(const std::filesystem::path& dir, const RealismReport& expected) {
  auto found = read_realism_shard(dir);
  if (!found.ok()) return found.status();
  if (found->scene != expected.scene || found->fingerprint != expected.fingerprint ||
      options_json(*found) != options_json(expected) || found->options.shard != expected.options.shard ||
      found->options.shards != expected.options.shards)
    return failed_precondition(dir.string() + " holds another study (" + shard_name(*found) + ", seed " +
                               std::to_string(found->options.seed) + ", scene fingerprint " + found->fingerprint + ")");
  for (const CaptureRangeReport& set : expected.studies)
    LFTRACK_RETURN_IF_ERROR(check_capture_range_shard_complete(dir / set.options.physics_name, set));
  return {};
}

Result<RealismReport> merge_realism_shards(const std::vector<RealismReport>& shards) {
  if (shards.empty()) return invalid_argument("merge: no shards given");
  const RealismReport& first = shards.front();
  for (const RealismReport& s : shards)
    if (s.scene != first.scene || s.fingerprint != first.fingerprint || options_json(s) != options_json(first) ||
        s.options.shards != first.options.shards)
      return failed_precondition("merge: " + shard_name(s) + " is of another study than " + shard_name(first));
  RealismReport merged = first;
  merged.options.shard = merged.options.shards = 1;
  merged.studies.clear();
  for (std::size_t i = 0; i < first.studies.size(); ++i) {
    std::vector<CaptureRangeReport> set_shards;
    for (const RealismReport& s : shards) set_shards.push_back(s.studies[i]);
    auto set = merge_capture_range_shards(set_shards);  // refuses a shard given twice or missing
    if (!set.ok()) return set.status().with_context("factor set " + first.studies[i].options.physics_name);
    merged.studies.push_back(std::move(set).value());
  }
  summarize(&merged);
  return merged;
}

Result<RealismReport> pool_realism_reports(const std::vector<RealismReport>& scenes) {
  if (scenes.empty()) return invalid_argument("pool: no scenes");
  RealismReport pooled = scenes.front();
  pooled.scene.clear();
  pooled.fingerprint.clear();
  pooled.studies.clear();
  for (const RealismReport& s : scenes) {
    if (options_json(s) != options_json(scenes.front()))
      return failed_precondition("pool: scene '" + s.scene + "' was studied with other options, methods or factor " +
                                 "sets than '" + scenes.front().scene + "' (each patient's scene must name the same "
                                 "registration, fiducial or not, and the same sets)");
    pooled.scene += (pooled.scene.empty() ? "" : " + ") + s.scene;
  }
  for (std::size_t i = 0; i < scenes.front().studies.size(); ++i) {
    std::vector<CaptureRangeReport> per_scene;
    for (const RealismReport& s : scenes) per_scene.push_back(s.studies[i]);
    // A set's physics may differ between patients (their scenes' sim.physics): the pooled set says
    // so rather than name one of them.
    const std::string description = per_scene.front().options.physics_description;
    const bool same = std::all_of(per_scene.begin(), per_scene.end(), [&](const CaptureRangeReport& r) {
      return r.options.physics_description == description;
    });
    if (!same)
      for (CaptureRangeReport& r : per_scene)
        r.options.physics_description = "each patient's own " + r.options.physics_name + " physics (they differ)";
    auto set = pool_capture_range_reports(per_scene);
    if (!set.ok()) return set.status().with_context("factor set " + per_scene.front().options.physics_name);
    pooled.studies.push_back(std::move(set).value());
  }
  pooled.options.per_bin = pooled.studies.front().options.per_bin;
  summarize(&pooled);
  return pooled;
}

}  // namespace lftrack::studies
