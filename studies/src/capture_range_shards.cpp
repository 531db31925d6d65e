// The capture-range study's shard files, merging and pooling (capture_range_study.hpp).

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <tuple>

#include "lftrack/studies/capture_range_study.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "csv_cells.hpp"

namespace lftrack::studies {
namespace {

const char* const kCaptureRunsHeader =
    "method,bin_lo_mm,bin_hi_mm,sample,initial_tre_mm,tre_mean_mm,tre_max_mm,success_2mm,success_2_5mm,"
    "evaluations,ms,accepted,verdict_reason";

nlohmann::json options_json(const CaptureRangeOptions& o) {
  nlohmann::json methods = nlohmann::json::array();
  for (const RegistrationMethod& m : o.methods) methods.push_back(m.label);
  return {{"methods", methods},
          {"per_bin", o.per_bin},
          {"bins", o.bins},
          {"bin_width_mm", o.bin_width_mm},
          {"success_mm", o.success_mm},
          {"success_loose_mm", o.success_loose_mm},
          {"gold_translation_mm", o.gold_translation_mm},
          {"gold_rotation_deg", o.gold_rotation_deg},
          {"max_start_rotation_deg", o.max_start_rotation_deg},
          {"seed", o.seed},
          {"renderer", o.renderer},
          {"physics", o.physics_name},
          {"physics_description",
           o.physics_description.empty() ? sim_spec::describe(o.physics) : o.physics_description},
          {"anatomy_draws", o.anatomy_draws}};
}

// The options two shards (or two scenes) must share to be one study.
bool same_study(const CaptureRangeOptions& a, const CaptureRangeOptions& b) {
  return options_json(a) == options_json(b);
}

std::string shard_name(const CaptureRangeReport& r) {
  return "shard " + std::to_string(r.options.shard) + "/" + std::to_string(r.options.shards) + " of scene '" +
         r.scene + "'";
}

Status parse_run(const std::vector<std::string>& c, const CaptureRangeOptions& o, const std::string& where,
                 CaptureRangeRun* run) {
  if (c.size() != 13) return corrupt_data(where + ": " + std::to_string(c.size()) + " fields, expected 13");
  run->method = c[0];
  if (std::none_of(o.methods.begin(), o.methods.end(),
                   [&](const RegistrationMethod& m) { return m.label == run->method; }))
    return corrupt_data(where + ": method '" + run->method + "' is not in study.json");
  double values[12];
  for (int i = 0; i < 12; ++i) {
    char* end = nullptr;
    values[i] = std::strtod(c[std::size_t(i) + 1].c_str(), &end);
    if (end == c[std::size_t(i) + 1].c_str() || *end || !std::isfinite(values[i]) || values[i] < 0)
      return corrupt_data(where + ": field " + std::to_string(i + 2) + " ('" + c[std::size_t(i) + 1] +
                          "') is not a number >= 0");
  }
  const double bin = values[0] / o.bin_width_mm;
  run->bin = int(std::lround(bin));
  run->sample = int(values[2]);
  if (std::abs(bin - run->bin) > 1e-6 || run->bin >= o.bins || run->sample != values[2] || run->sample >= o.per_bin)
    return corrupt_data(where + ": bin or sample outside the study");
  run->initial_tre_mm = values[3];
  run->tre_mean_mm = values[4];
  run->tre_max_mm = values[5];
  run->success = values[6] != 0;
  run->success_loose = values[7] != 0;
  if (values[8] > 1e9 || std::abs(values[1] - values[0] - o.bin_width_mm) > 1e-6 * o.bin_width_mm)
    return corrupt_data(where + ": evaluations or bin edges out of range");
  run->evaluations = int(values[8]);
  run->ms = values[9];
  if ((values[10] != 0 && values[10] != 1) || values[11] != std::floor(values[11]) || values[11] > 255)
    return corrupt_data(where + ": accepted or verdict_reason out of range");
  run->accepted = values[10] != 0;
  run->verdict_reason = int(values[11]);
  return {};
}

}  // namespace

Status write_capture_range_shard(const CaptureRangeReport& report, const std::filesystem::path& dir,
                                 bool describe) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return io_error(dir.string() + ": cannot create folder: " + ec.message());
  // An earlier description goes first: a folder being rewritten never reads as a result.
  std::filesystem::remove(dir / "study.json", ec);
  if (ec) return io_error((dir / "study.json").string() + ": cannot remove the earlier description");
  const CaptureRangeOptions& o = report.options;
  std::ostringstream csv;
  csv << kCaptureRunsHeader << '\n';
  for (const CaptureRangeRun& r : report.runs)
    csv << r.method << ',' << csv_number(r.bin * o.bin_width_mm) << ',' << csv_number((r.bin + 1) * o.bin_width_mm) << ','
        << r.sample << ',' << csv_number(r.initial_tre_mm) << ',' << csv_number(r.tre_mean_mm) << ',' << csv_number(r.tre_max_mm)
        << ',' << int(r.success) << ',' << int(r.success_loose) << ',' << r.evaluations << ',' << csv_number(r.ms)
        << ',' << int(r.accepted) << ',' << r.verdict_reason << '\n';
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(dir / "runs.csv", csv.str()));
  return describe ? write_capture_range_description(report, dir) : Status{};
}

Status write_capture_range_description(const CaptureRangeReport& report, const std::filesystem::path& dir) {
  const CaptureRangeOptions& o = report.options;
  nlohmann::json j = {{"study", "capture-range"},
                      {"scene", report.scene},
                      {"fingerprint", report.fingerprint},
                      {"shard", o.shard},
                      {"shards", o.shards},
                      {"runs", report.runs.size()},
                      {"options", options_json(o)}};
  return write_file_atomically(dir / "study.json", j.dump(2) + "\n");
}

Result<CaptureRangeReport> read_capture_range_shard(const std::filesystem::path& dir) {
  CaptureRangeReport r;
  CaptureRangeOptions& o = r.options;
  std::size_t runs_expected = 0;
  {
    const auto file = dir / "study.json";
    std::ifstream in(file);
    if (!in) return not_found(file.string() + ": no such file (not a study folder?)");
    try {
      const auto j = nlohmann::json::parse(in);
      if (j.value("study", "") != "capture-range")
        return failed_precondition(file.string() + ": not a capture-range study");
      r.scene = j.at("scene").get<std::string>();
      r.fingerprint = j.value("fingerprint", "");
      const auto shard = j.at("shard").get<std::int64_t>();
      const auto shards = j.at("shards").get<std::int64_t>();
      LFTRACK_RETURN_IF_ERROR(check_shard_position(shard, shards, file));
      o.shard = int(shard);
      o.shards = int(shards);
      runs_expected = j.at("runs").get<std::size_t>();
      const auto& opt = j.at("options");
      o.methods.clear();
      for (const auto& label : opt.at("methods")) {
        auto m = parse_registration_method(label.get<std::string>());
        if (!m.ok()) return m.status().with_context(file.string());
        o.methods.push_back(*m);
      }
      const auto per_bin = opt.at("per_bin").get<std::int64_t>();
      const auto bins = opt.at("bins").get<std::int64_t>();
      if (per_bin < 1 || per_bin > 1000000 || bins < 1 || bins > 32)
        return corrupt_data(file.string() + ": per_bin or bins out of range");
      o.per_bin = int(per_bin);
      o.bins = int(bins);
      o.bin_width_mm = opt.at("bin_width_mm").get<double>();
      o.success_mm = opt.at("success_mm").get<double>();
      o.success_loose_mm = opt.at("success_loose_mm").get<double>();
      o.gold_translation_mm = opt.at("gold_translation_mm").get<double>();
      o.gold_rotation_deg = opt.at("gold_rotation_deg").get<double>();
      o.max_start_rotation_deg = opt.at("max_start_rotation_deg").get<double>();
      o.seed = opt.at("seed").get<std::uint64_t>();
      o.renderer = opt.at("renderer").get<std::string>();
      // Studies from before issue 21 had ideal frames.
      o.physics_name = opt.value("physics", std::string("ideal"));
      o.physics_description =
          opt.value("physics_description", sim_spec::describe(sim_spec::XrayPhysicsSpec{}));
      o.anatomy_draws = opt.value("anatomy_draws", 1);
      if (o.anatomy_draws < 1 || o.anatomy_draws > 100000) return corrupt_data(file.string() + ": anatomy_draws out of range");
    } catch (const std::exception& e) {
      return corrupt_data(file.string() + ": " + e.what());
    }
    if (!(o.bin_width_mm > 0) || !std::isfinite(o.bin_width_mm) || o.methods.empty())
      return corrupt_data(file.string() + ": bin width or methods out of range");
  }
  const auto file = dir / "runs.csv";
  std::ifstream csv(file);
  if (!csv) return not_found(file.string() + ": no such file");
  std::string line;
  if (!std::getline(csv, line) || line != kCaptureRunsHeader)
    return corrupt_data(file.string() + ": line 1 is not the capture-range header");
  int line_no = 1;
  std::set<std::tuple<int, int, std::string>> seen;
  while (std::getline(csv, line)) {
    ++line_no;
    if (line.empty()) continue;
    CaptureRangeRun run;
    const std::string where = file.string() + ":" + std::to_string(line_no);
    LFTRACK_RETURN_IF_ERROR(parse_run(split_csv_line(line), o, where, &run));
    if (run.sample % o.shards != o.shard - 1)
      return corrupt_data(where + ": sample " + std::to_string(run.sample) + " is not shard " +
                          std::to_string(o.shard) + "/" + std::to_string(o.shards) + "'s");
    if (!seen.insert({run.sample, run.bin, run.method}).second)
      return corrupt_data(where + ": sample " + std::to_string(run.sample) + ", bin " + std::to_string(run.bin) +
                          ", method " + run.method + " twice");
    r.runs.push_back(run);
  }
  if (r.runs.size() != runs_expected)
    return corrupt_data(file.string() + ": " + std::to_string(r.runs.size()) + " runs, study.json says " +
                        std::to_string(runs_expected));
  r.summaries = summarize_capture_range(o, r.runs);
  return r;
}

Status check_capture_range_shard_complete(const std::filesystem::path& dir, const CaptureRangeReport& expected) {
  auto found = read_capture_range_shard(dir);
  if (!found.ok()) return found.status();
  const CaptureRangeOptions& o = expected.options;
  if (found->scene != expected.scene || found->fingerprint != expected.fingerprint ||
      !same_study(found->options, o) || found->options.shard != o.shard ||
      found->options.shards != o.shards)
    return failed_precondition(dir.string() + " holds another study (" + shard_name(*found) + ", seed " +
                               std::to_string(found->options.seed) + ", scene fingerprint " +
                               (found->fingerprint.empty() ? "none" : found->fingerprint) + ")");
  const std::size_t want = std::size_t(capture_range_shard_samples(o)) * std::size_t(o.bins) * o.methods.size();
  if (found->runs.size() != want)
    return corrupt_data(dir.string() + ": " + std::to_string(found->runs.size()) + " runs of " + std::to_string(want));
  return {};
}

Result<CaptureRangeReport> merge_capture_range_shards(const std::vector<CaptureRangeReport>& shards) {
  if (shards.empty()) return invalid_argument("merge: no shards given");
  const CaptureRangeReport& first = shards.front();
  CaptureRangeReport merged;
  merged.scene = first.scene;
  merged.fingerprint = first.fingerprint;
  merged.options = first.options;
  merged.options.shard = merged.options.shards = 1;
  std::set<int> seen;
  for (const CaptureRangeReport& s : shards) {
    if (s.scene != first.scene || s.fingerprint != first.fingerprint || !same_study(s.options, first.options) ||
        s.options.shards != first.options.shards)
      return failed_precondition("merge: " + shard_name(s) + " is of another study than " + shard_name(first));
    if (!seen.insert(s.options.shard).second)
      return failed_precondition("merge: " + shard_name(s) + " given twice");
    merged.runs.insert(merged.runs.end(), s.runs.begin(), s.runs.end());
  }
  for (int k = 1; k <= first.options.shards; ++k)
    if (!seen.count(k))
      return failed_precondition("merge: shard " + std::to_string(k) + " of " + std::to_string(first.options.shards) +
                                 " is missing");
  // The whole study's order: sample, then bin, then method.
  std::map<std::string, std::size_t> method_order;
  for (std::size_t m = 0; m < merged.options.methods.size(); ++m) method_order[merged.options.methods[m].label] = m;
  std::stable_sort(merged.runs.begin(), merged.runs.end(), [&](const CaptureRangeRun& a, const CaptureRangeRun& b) {
    return std::make_tuple(a.sample, a.bin, method_order[a.method]) <
           std::make_tuple(b.sample, b.bin, method_order[b.method]);
  });
  const std::size_t want =
      std::size_t(merged.options.per_bin) * std::size_t(merged.options.bins) * merged.options.methods.size();
  if (merged.runs.size() != want)
    return failed_precondition("merge: " + std::to_string(merged.runs.size()) + " runs, the study has " +
                               std::to_string(want));
  merged.summaries = summarize_capture_range(merged.options, merged.runs);
  return merged;
}

Result<CaptureRangeReport> pool_capture_range_reports(const std::vector<CaptureRangeReport>& scenes) {
  if (scenes.empty()) return invalid_argument("pool: no scenes");
  CaptureRangeReport pooled;
  pooled.options = scenes[0].options;
  std::set<std::string> names;
  int offset = 0;
  for (const CaptureRangeReport& s : scenes) {
    if (!names.insert(s.scene).second) return failed_precondition("pool: scene '" + s.scene + "' given twice");
    CaptureRangeOptions a = s.options, b = scenes[0].options;
    if (!same_study(a, b)) return failed_precondition("pool: scene '" + s.scene + "' was studied with other options");
    pooled.scene += (pooled.scene.empty() ? "" : " + ") + s.scene;
    for (CaptureRangeRun run : s.runs) {
      run.sample += offset;
      pooled.runs.push_back(run);
    }
    offset += s.options.per_bin;
  }
  pooled.options.per_bin = offset;
  pooled.options.shard = pooled.options.shards = 1;
  pooled.summaries = summarize_capture_range(pooled.options, pooled.runs);
  return pooled;
}

}  // namespace lftrack::studies
