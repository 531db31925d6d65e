// The trade study's files: the points CSV and study description of a shard, merging shards, the
// Pareto front, the recommended defaults, the two plots and summary.md.

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "lftrack/studies/plot.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "csv_cells.hpp"
#include "lftrack/studies/trade_study.hpp"
#include "lftrack/studies/verdict_outcomes.hpp"
#include "quantile.hpp"

namespace lftrack::studies {
namespace {

// runs.csv: before the verdict was recorded, and since (accepted and verdict_reason as
// capture-range's runs.csv has them; empty cells: a point not judged).
const char* const kRunsHeaderWithoutVerdict = "id,problem,tre_mm,ms";
const std::string kRunsHeader = std::string(kRunsHeaderWithoutVerdict) + ",accepted,verdict_reason";

// points.csv before failed registrations were recorded: its failed runs are the NaN times of
// runs.csv, their reason unknown.
const char* const kCsvHeaderWithoutFailures =
    "id,renderer,storage,vq_codebook,lf_u,lf_v,lf_s,lf_t,envelope_scale,octree_pivot,bin,similarity,plan,"
    "final_step_mm,budget_ms,runs,median_ms,p95_ms,mean_tre_mm,p95_tre_mm,success_rate,memory_bytes,"
    "precompute_s,ncc_vs_siddon,psnr_db_vs_siddon";
const std::string kCsvHeaderWithoutVerdict = std::string(kCsvHeaderWithoutFailures) + ",failed_runs,failure";
// Since the verdict: its four outcomes per point (verdict_outcomes.hpp; all 0: not judged).
const std::string kCsvHeader =
    kCsvHeaderWithoutVerdict + ",accepted_right,false_accepts,false_rejects,rejected_wrong";

// A free text as one CSV cell (no quoting: commas become ';') and one table cell (no '|').
std::string text_cell(std::string text) {
  for (char& c : text)
    if (c == ',') c = ';';
    else if (c == '|') c = '/';
    else if (c == '\n' || c == '\r') c = ' ';
  return text;
}

// How a point is set, in words.
std::string describe(const TradePoint& t) {
  std::string s = t.renderer;
  if (t.renderer == "lightfield") {
    s += " " + t.storage + (t.storage == "vq" ? std::to_string(t.vq_codebook) : "") + " " +
         std::to_string(t.lf_resolution[0]) + "x" + std::to_string(t.lf_resolution[1]) + "x" +
         std::to_string(t.lf_resolution[2]) + "x" + std::to_string(t.lf_resolution[3]);
    if (t.envelope_scale != 1) s += ", envelope x" + csv_number(t.envelope_scale);
  }
  if (t.renderer == "octree") s += " P=" + csv_number(t.octree_pivot);
  s += ", bin " + std::to_string(t.bin) + ", " + t.similarity + ", plan " + t.plan + ", final step " +
       csv_number(t.final_step_mm) + " mm, " +
       (t.budget_ms > 0 ? "budget " + csv_number(t.budget_ms) + " ms" : "no budget");
  return s;
}

std::string mb(double bytes) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", bytes / 1e6);
  return buf;
}

std::string fixed(double v, int decimals) {
  if (!std::isfinite(v)) return std::isnan(v) ? "n/a" : "exact";
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

// "k of n registrations failed: reason".
std::string failure_text(const TradeResult& r) {
  return std::to_string(r.failed_runs) + " of " + std::to_string(r.runs) + " registrations failed: " +
         (r.failure.empty() ? "(reason not recorded)" : text_cell(r.failure));
}

// A point whose every registration failed has no time, TRE or success to show: those cells say
// "failed"; the renderer's memory, precompute and fidelity were measured and are shown.
std::string table_row(const TradeResult& r) {
  const bool none_ran = r.failed() && r.failed_runs >= r.runs;
  const auto outcome = [&](double v, int decimals) { return none_ran ? std::string("failed") : fixed(v, decimals); };
  return "| " + r.point.id + " | " + outcome(r.median_ms, 1) + " | " + outcome(r.p95_ms, 1) + " | " +
         outcome(r.mean_tre_mm, 3) + " | " + outcome(r.p95_tre_mm, 3) + " | " +
         (none_ran ? std::string("failed") : fixed(100 * r.success_rate, 0) + "%") + " | " + mb(r.memory_bytes) +
         " | " + fixed(r.precompute_s, 1) + " | " + fixed(r.psnr_db_vs_siddon, 1) + " | " + describe(r.point) +
         (r.failed() ? "; **FAILED**, " + failure_text(r) : std::string()) + " |\n";
}

const char* const kTableHeader =
    "| point | median ms | p95 ms | mean TRE mm | p95 TRE mm | success | memory MB | precompute s | PSNR dB "
    "vs "
    "Siddon | settings |\n|---|---|---|---|---|---|---|---|---|---|\n";

nlohmann::json study_json(const TradeStudy& s) {
  return {{"study", "trade"},
          {"scene", s.scene},
          {"fingerprint", s.fingerprint},
          {"seed", s.seed},
          {"problems", s.problems},
          {"quick", s.quick},
          {"shard", s.shard},
          {"shards", s.shards},
          {"points_total", s.points_total},
          {"physics", s.physics},
          {"physics_description", s.physics_description},
          {"verdict_tolerance_mm", s.verdict_tolerance_mm},
          {"points", s.results.size()}};
}

// Fills each result's per-problem rows from runs.csv, if there is one (folders written before
// it existed have none). Rows must name known points and come in the problems' order.
Status read_trade_runs(const std::filesystem::path& file, TradeStudy* s) {
  std::ifstream in(file);
  if (!in) return {};
  std::map<std::string, TradeResult*> by_id;
  for (TradeResult& r : s->results) by_id[r.point.id] = &r;
  std::string line;
  if (!std::getline(in, line) || (line != kRunsHeader && line != kRunsHeaderWithoutVerdict))
    return corrupt_data(file.string() + ": line 1 is not the trade study's runs header");
  const std::size_t columns = line == kRunsHeader ? 6 : 4;
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty()) continue;
    const auto c = split_csv_line(line);
    const std::string where = file.string() + ":" + std::to_string(line_no);
    if (c.size() != columns)
      return corrupt_data(where + ": " + std::to_string(c.size()) + " fields, expected " + std::to_string(columns));
    auto it = by_id.find(c[0]);
    if (it == by_id.end()) return corrupt_data(where + ": point '" + c[0] + "' is not in points.csv");
    TradeResult& r = *it->second;
    char* end = nullptr;
    const long k = std::strtol(c[1].c_str(), &end, 10);
    if (*end || k != long(r.problem_tre_mm.size()))
      return corrupt_data(where + ": problem '" + c[1] + "' out of order for point '" + c[0] + "'");
    const double tre = std::strtod(c[2].c_str(), &end);
    if (*end || !std::isfinite(tre) || tre < 0) return corrupt_data(where + ": TRE '" + c[2] + "' is not a distance");
    const double ms = std::strtod(c[3].c_str(), &end);
    if (*end || !(std::isnan(ms) || (std::isfinite(ms) && ms >= 0)))
      return corrupt_data(where + ": time '" + c[3] + "' is not a duration");
    if (columns == 6 && !(c[4].empty() && c[5].empty())) {  // empty: this point was not judged
      const long accepted = std::strtol(c[4].c_str(), &end, 10);
      const bool accepted_ok = !c[4].empty() && !*end && (accepted == 0 || accepted == 1);
      const long reason = std::strtol(c[5].c_str(), &end, 10);
      if (!accepted_ok || c[5].empty() || *end || reason < 0 || reason > 255 ||
          r.problem_accepted.size() != r.problem_tre_mm.size())
        return corrupt_data(where + ": accepted or verdict_reason out of range");
      r.problem_accepted.push_back(int(accepted));
      r.problem_verdict_reason.push_back(int(reason));
    }
    r.problem_tre_mm.push_back(tre);
    r.problem_ms.push_back(ms);
  }
  return {};
}

// The verdict's table in summary.md: one row per point.
std::string verdict_row(const TradeResult& r) {
  if (!r.judged()) return "| " + r.point.id + " | " + std::to_string(r.runs) + " | not judged | | | |\n";
  const VerdictOutcomes& v = r.verdict;
  return "| " + r.point.id + " | " + std::to_string(v.total()) + " | " + std::to_string(v.accepted_right) + " | " +
         std::to_string(v.accepted_wrong) + " | " + std::to_string(v.rejected_right) + " | " +
         std::to_string(v.rejected_wrong) + " |\n";
}

}  // namespace

VerdictOutcomes tally_trade_verdict(const TradeResult& r, double tolerance_mm) {
  VerdictOutcomes v;
  if (r.problem_accepted.empty() || r.problem_accepted.size() != r.problem_tre_mm.size()) return v;
  for (std::size_t k = 0; k < r.problem_tre_mm.size(); ++k) {
    const bool ran = k < r.problem_ms.size() && !std::isnan(r.problem_ms[k]);  // NaN: the registration failed
    v.add(r.problem_accepted[k] != 0, ran && r.problem_tre_mm[k] < tolerance_mm);
  }
  return v;
}

std::vector<TradeResult> pareto_front(const std::vector<TradeResult>& results) {
  const auto contends = [](const TradeResult& r) {
    return !r.failed() && r.success_rate > 0 && std::isfinite(r.median_ms) && std::isfinite(r.mean_tre_mm);
  };
  std::vector<TradeResult> front;
  for (const TradeResult& a : results) {
    if (!contends(a)) continue;
    bool dominated = false;
    for (const TradeResult& b : results) {
      if (!contends(b)) continue;
      if (b.median_ms <= a.median_ms && b.mean_tre_mm <= a.mean_tre_mm &&
          (b.median_ms < a.median_ms || b.mean_tre_mm < a.mean_tre_mm)) {
        dominated = true;
        break;
      }
    }
    if (!dominated) front.push_back(a);
  }
  std::sort(front.begin(), front.end(),
            [](const TradeResult& x, const TradeResult& y) { return x.median_ms < y.median_ms; });
  return front;
}

TradeRecommendations recommend(const std::vector<TradeResult>& results) {
  TradeRecommendations r;
  for (const TradeResult& x : results) {
    if (x.success_rate < 0.95 || x.failed()) continue;
    if (x.mean_tre_mm <= 1.0 && (!r.has_fastest || x.median_ms < r.fastest_within_1mm.median_ms)) {
      r.fastest_within_1mm = x;
      r.has_fastest = true;
    }
    if (x.p95_ms <= 100.0 && (!r.has_accurate || x.mean_tre_mm < r.most_accurate_within_100ms.mean_tre_mm)) {
      r.most_accurate_within_100ms = x;
      r.has_accurate = true;
    }
    if (x.mean_tre_mm <= 0.5 &&
        (!r.has_least_memory || x.memory_bytes < r.least_memory_within_half_mm.memory_bytes)) {
      r.least_memory_within_half_mm = x;
      r.has_least_memory = true;
    }
  }
  return r;
}

namespace {

Status write_trade_description(const TradeStudy& study, const std::filesystem::path& dir) {
  return write_file_atomically(dir / "study.json", study_json(study).dump(2) + "\n");
}

// points.csv and runs.csv, then (if `describe_now`) study.json. An earlier study.json goes
// first, so a folder being rewritten never reads as a result.
Status write_trade_data(const TradeStudy& study, const std::filesystem::path& dir, bool describe_now) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return io_error(dir.string() + ": cannot create folder: " + ec.message());
  std::filesystem::remove(dir / "study.json", ec);
  if (ec) return io_error((dir / "study.json").string() + ": cannot remove the earlier description");
  std::ostringstream csv;
  csv << kCsvHeader << '\n';
  for (const TradeResult& r : study.results) {
    const TradePoint& t = r.point;
    csv << t.id << ',' << t.renderer << ',' << t.storage << ',' << t.vq_codebook << ',' << t.lf_resolution[0]
        << ',' << t.lf_resolution[1] << ',' << t.lf_resolution[2] << ',' << t.lf_resolution[3] << ','
        << csv_number(t.envelope_scale) << ',' << csv_number(t.octree_pivot) << ',' << t.bin << ',' << t.similarity << ','
        << t.plan << ',' << csv_number(t.final_step_mm) << ',' << csv_number(t.budget_ms) << ',' << r.runs << ','
        << csv_number(r.median_ms) << ',' << csv_number(r.p95_ms) << ',' << csv_number(r.mean_tre_mm) << ',' << csv_number(r.p95_tre_mm)
        << ',' << csv_number(r.success_rate) << ',' << csv_number(r.memory_bytes) << ',' << csv_number(r.precompute_s) << ','
        << csv_number(r.ncc_vs_siddon) << ',' << csv_number(r.psnr_db_vs_siddon) << ',' << r.failed_runs << ','
        << text_cell(r.failure) << ',' << r.verdict.accepted_right << ',' << r.verdict.accepted_wrong << ','
        << r.verdict.rejected_right << ',' << r.verdict.rejected_wrong << '\n';
  }
  std::ostringstream runs;
  runs << kRunsHeader << '\n';
  for (const TradeResult& r : study.results) {
    const bool judged = r.problem_accepted.size() == r.problem_tre_mm.size() &&
                        r.problem_verdict_reason.size() == r.problem_tre_mm.size();
    for (std::size_t k = 0; k < r.problem_tre_mm.size(); ++k) {
      runs << r.point.id << ',' << k << ',' << csv_number(r.problem_tre_mm[k]) << ','
           << csv_number(k < r.problem_ms.size() ? r.problem_ms[k] : std::nan("")) << ',';
      if (judged) runs << r.problem_accepted[k] << ',' << r.problem_verdict_reason[k];
      else runs << ',';  // not judged: empty cells
      runs << '\n';
    }
  }
  // study.json last: a folder without it is not a result (study_shard.hpp).
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(dir / "points.csv", csv.str()));
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(dir / "runs.csv", runs.str()));
  if (!describe_now) return {};
  return write_trade_description(study, dir);
}

}  // namespace

Status write_trade_shard(const TradeStudy& study, const std::filesystem::path& dir) {
  return write_trade_data(study, dir, true);
}

Result<TradeStudy> read_trade_shard(const std::filesystem::path& dir) {
  TradeStudy s;
  {
    std::ifstream in(dir / "study.json");
    if (!in) return not_found((dir / "study.json").string() + ": no such file (not a trade study folder?)");
    try {
      const auto j = nlohmann::json::parse(in);
      if (j.value("study", "trade") != "trade")
        return failed_precondition((dir / "study.json").string() + ": a " + j.value("study", "") +
                                   " study, not a trade study");
      s.scene = j.at("scene").get<std::string>();
      s.fingerprint = j.value("fingerprint", "");
      s.seed = j.at("seed").get<std::uint64_t>();
      const auto problems = j.at("problems").get<std::int64_t>();
      s.quick = j.at("quick").get<bool>();
      s.physics = j.value("physics", std::string("ideal"));  // studies before issue 21: ideal frames
      s.physics_description = j.value("physics_description", std::string());
      s.verdict_tolerance_mm = j.value("verdict_tolerance_mm", 2.0);  // studies before the verdict: the default
      if (!std::isfinite(s.verdict_tolerance_mm) || s.verdict_tolerance_mm < 0)
        return corrupt_data((dir / "study.json").string() + ": verdict_tolerance_mm out of range");
      const auto shard = j.at("shard").get<std::int64_t>();
      const auto shards = j.at("shards").get<std::int64_t>();
      const auto points_total = j.at("points_total").get<std::int64_t>();
      if (problems < 1 || problems > 1000000 || shards < 1 || shards > 10000 || shard < 1 || shard > shards ||
          points_total < 0 || points_total > 100000)
        return corrupt_data((dir / "study.json").string() + ": problems, shard k/n or points out of range");
      s.problems = int(problems);
      s.shard = int(shard);
      s.shards = int(shards);
      s.points_total = int(points_total);
    } catch (const std::exception& e) {
      return corrupt_data((dir / "study.json").string() + ": " + e.what());
    }
  }
  const auto file = dir / "points.csv";
  std::ifstream csv(file);
  if (!csv) return not_found(file.string() + ": no such file");
  std::string line;
  if (!std::getline(csv, line) ||
      (line != kCsvHeader && line != kCsvHeaderWithoutVerdict && line != kCsvHeaderWithoutFailures))
    return corrupt_data(file.string() + ": line 1 is not the trade study's header");
  const bool records_failures = line != kCsvHeaderWithoutFailures;
  const bool records_verdict = line == kCsvHeader;
  const std::size_t fields = records_verdict ? 31 : records_failures ? 27 : 25;
  int line_no = 1;
  while (std::getline(csv, line)) {
    ++line_no;
    if (line.empty()) continue;
    const auto c = split_csv_line(line);
    const std::string where = file.string() + ":" + std::to_string(line_no);
    if (c.size() != fields)
      return corrupt_data(where + ": " + std::to_string(c.size()) + " fields, expected " + std::to_string(fields));
    TradeResult r;
    TradePoint& t = r.point;
    std::size_t k = 0;
    auto integer = [&](long lo, long hi, int* out) {
      const std::string& text = c[k++];
      char* end = nullptr;
      errno = 0;
      const long v = std::strtol(text.c_str(), &end, 10);
      if (text.empty() || *end || errno || v < lo || v > hi) return false;
      *out = int(v);
      return true;
    };
    // lo..hi for finite values; NaN and infinities only where `special` allows them.
    auto real = [&](double lo, double hi, bool special, double* out) {
      const std::string& text = c[k++];
      char* end = nullptr;
      const double v = std::strtod(text.c_str(), &end);
      if (text.empty() || *end) return false;
      if (!std::isfinite(v) ? !special : (v < lo || v > hi)) return false;
      *out = v;
      return true;
    };
    constexpr double kBig = 1e15;
    t.id = c[k++];
    t.renderer = c[k++];
    t.storage = c[k++];
    bool ok = integer(0, 1 << 24, &t.vq_codebook);
    for (int a = 0; a < 4; ++a) ok = ok && integer(1, 1 << 16, &t.lf_resolution[std::size_t(a)]);
    ok = ok && real(0, kBig, false, &t.envelope_scale) && real(0, kBig, false, &t.octree_pivot) &&
         integer(1, 1024, &t.bin);
    t.similarity = c[k++];
    t.plan = c[k++];
    ok = ok && real(0, kBig, false, &t.final_step_mm) && real(0, kBig, false, &t.budget_ms) &&
         integer(1, 1000000, &r.runs) && real(0, kBig, true, &r.median_ms) && real(0, kBig, true, &r.p95_ms) &&
         real(0, kBig, false, &r.mean_tre_mm) && real(0, kBig, false, &r.p95_tre_mm) &&
         real(0, 1, false, &r.success_rate) && real(0, kBig, false, &r.memory_bytes) &&
         real(0, kBig, false, &r.precompute_s) && real(-1, 1, true, &r.ncc_vs_siddon) &&
         real(-kBig, kBig, true, &r.psnr_db_vs_siddon);
    if (ok && records_failures) {
      ok = integer(0, r.runs, &r.failed_runs);
      r.failure = c[k++];
    }
    if (ok && records_verdict)
      ok = integer(0, r.runs, &r.verdict.accepted_right) && integer(0, r.runs, &r.verdict.accepted_wrong) &&
           integer(0, r.runs, &r.verdict.rejected_right) && integer(0, r.runs, &r.verdict.rejected_wrong);
    if (!ok) return corrupt_data(where + ": field " + std::to_string(k) + " ('" + c[k - 1] + "') is not a valid value");
    if (r.judged() && r.verdict.total() != r.runs)
      return corrupt_data(where + ": the verdict's outcomes count " + std::to_string(r.verdict.total()) + " of " +
                          std::to_string(r.runs) + " runs");
    if (t.id.empty()) return corrupt_data(where + ": empty point id");
    s.results.push_back(r);
  }
  LFTRACK_RETURN_IF_ERROR(read_trade_runs(dir / "runs.csv", &s));
  if (!records_failures)
    for (TradeResult& r : s.results)
      r.failed_runs = int(std::count_if(r.problem_ms.begin(), r.problem_ms.end(), [](double ms) { return std::isnan(ms); }));
  return s;
}

Result<TradeStudy> merge_trade_shards(const std::vector<TradeStudy>& shards) {
  if (shards.empty()) return invalid_argument("merge: no shards given");
  const TradeStudy& first = shards.front();
  TradeStudy merged = first;
  merged.results.clear();
  std::set<int> seen;
  std::set<std::string> ids;
  for (const TradeStudy& s : shards) {
    if (s.scene != first.scene || s.fingerprint != first.fingerprint || s.seed != first.seed ||
        s.problems != first.problems ||
        s.quick != first.quick || s.shards != first.shards || s.points_total != first.points_total ||
        s.physics != first.physics || s.physics_description != first.physics_description ||
        s.verdict_tolerance_mm != first.verdict_tolerance_mm)
      return failed_precondition("merge: shard " + std::to_string(s.shard) + "/" + std::to_string(s.shards) +
                                 " is of another study (scene '" + s.scene + "', seed " +
                                 std::to_string(s.seed) + ", " + std::to_string(s.problems) + " problems)");
    if (!seen.insert(s.shard).second)
      return failed_precondition("merge: shard " + std::to_string(s.shard) + " given twice");
    for (const TradeResult& r : s.results)
      if (!ids.insert(r.point.id).second)
        return failed_precondition("merge: point '" + r.point.id + "' measured twice");
  }
  // The whole study's order: point i was the (i / n)-th point of shard i % n + 1.
  for (std::size_t i = 0;; ++i) {
    const std::size_t n = std::size_t(first.shards), position = i / n;
    const int shard = int(i % n) + 1;
    auto it = std::find_if(shards.begin(), shards.end(), [&](const TradeStudy& s) { return s.shard == shard; });
    if (it == shards.end()) break;  // a missing shard: reported below
    if (position >= it->results.size()) {
      if (std::all_of(shards.begin(), shards.end(), [&](const TradeStudy& s) { return position >= s.results.size(); }))
        break;
      continue;
    }
    merged.results.push_back(it->results[position]);
  }
  for (int k = 1; k <= first.shards; ++k)
    if (!seen.count(k))
      return failed_precondition("merge: shard " + std::to_string(k) + " of " + std::to_string(first.shards) +
                                 " is missing");
  if (int(merged.results.size()) != first.points_total)
    return failed_precondition("merge: " + std::to_string(merged.results.size()) + " points, the study has " +
                               std::to_string(first.points_total));
  merged.shard = merged.shards = 1;
  return merged;
}

Status check_trade_shard_complete(const std::filesystem::path& dir, const TradeStudy& expected,
                                  const std::vector<std::string>& ids) {
  auto s = read_trade_shard(dir);
  if (!s.ok()) return s.status();
  if (s->scene != expected.scene || s->fingerprint != expected.fingerprint || s->seed != expected.seed ||
      s->problems != expected.problems ||
      s->quick != expected.quick || s->shard != expected.shard || s->shards != expected.shards ||
      s->points_total != expected.points_total || s->physics != expected.physics ||
      s->physics_description != expected.physics_description ||
      s->verdict_tolerance_mm != expected.verdict_tolerance_mm)
    return failed_precondition(dir.string() + " holds another study (scene '" + s->scene + "', seed " +
                               std::to_string(s->seed) + ", " + std::to_string(s->problems) +
                               " problems, shard " + std::to_string(s->shard) + "/" + std::to_string(s->shards) +
                               ", " + std::to_string(s->points_total) + " points in all, " + s->physics +
                               " physics, scene fingerprint " +
                               (s->fingerprint.empty() ? "none" : s->fingerprint) + ")");
  std::vector<std::string> found;
  for (const TradeResult& r : s->results) {
    found.push_back(r.point.id);
    if (int(r.problem_tre_mm.size()) != expected.problems || r.runs != expected.problems)
      return corrupt_data(dir.string() + ": point '" + r.point.id + "' has " +
                          std::to_string(r.problem_tre_mm.size()) + " problem rows of " +
                          std::to_string(expected.problems));
    if (!r.judged() || r.problem_accepted.size() != r.problem_tre_mm.size())
      return corrupt_data(dir.string() + ": point '" + r.point.id +
                          "' has no registration verdict (written before the verdict was recorded)");
  }
  if (found != ids) {
    std::string want;
    for (const auto& id : ids) want += (want.empty() ? "" : ",") + id;
    return corrupt_data(dir.string() + ": its points are not this shard's (" + want + ")");
  }
  return {};
}

Result<TradeStudy> pool_trade_studies(const std::vector<TradeStudy>& scenes, std::vector<std::string>* left_out) {
  if (scenes.empty()) return invalid_argument("pool: no scenes");
  std::set<std::string> names;
  for (const TradeStudy& s : scenes) {
    if (!names.insert(s.scene).second) return failed_precondition("pool: scene '" + s.scene + "' given twice");
    if (s.seed != scenes[0].seed || s.problems != scenes[0].problems || s.quick != scenes[0].quick ||
        s.physics != scenes[0].physics)
      return failed_precondition("pool: scene '" + s.scene + "' was studied with another seed, problem count, "
                                 "size or physics than '" + scenes[0].scene + "'");
    for (const TradeResult& r : s.results)
      if (int(r.problem_tre_mm.size()) != r.runs || r.problem_ms.size() != r.problem_tre_mm.size())
        return failed_precondition("pool: scene '" + s.scene + "', point '" + r.point.id +
                                   "' has no per-problem rows (runs.csv); run its study again");
  }
  TradeStudy pooled = scenes[0];
  pooled.scene.clear();
  pooled.fingerprint.clear();
  for (const TradeStudy& s : scenes) pooled.scene += (pooled.scene.empty() ? "" : " + ") + s.scene;
  pooled.problems = 0;
  for (const TradeStudy& s : scenes) pooled.problems += s.problems;
  for (const TradeStudy& s : scenes)  // scenes of different tolerances: each its own (0)
    if (s.verdict_tolerance_mm != pooled.verdict_tolerance_mm) pooled.verdict_tolerance_mm = 0;
  pooled.results.clear();
  std::set<std::string> dropped;
  for (const TradeResult& first : scenes[0].results) {
    std::vector<const TradeResult*> same;
    std::vector<const TradeStudy*> scene_of;  // the scene of each of `same`
    for (const TradeStudy& s : scenes)
      for (const TradeResult& r : s.results)
        if (r.point.id == first.point.id) {
          same.push_back(&r);
          scene_of.push_back(&s);
        }
    if (same.size() != scenes.size()) {
      dropped.insert(first.point.id);
      continue;
    }
    TradeResult p = first;
    p.problem_tre_mm.clear();
    p.problem_ms.clear();
    p.problem_accepted.clear();
    p.problem_verdict_reason.clear();
    p.verdict = {};
    // The verdict, where every scene judged the point: each scene's rows against its own tolerance.
    const bool judged = std::all_of(same.begin(), same.end(), [](const TradeResult* r) {
      return r->problem_accepted.size() == r->problem_tre_mm.size() &&
             r->problem_verdict_reason.size() == r->problem_tre_mm.size() && !r->problem_accepted.empty();
    });
    p.memory_bytes = p.precompute_s = p.ncc_vs_siddon = p.psnr_db_vs_siddon = 0;
    for (std::size_t i = 0; i < same.size(); ++i) {
      const TradeResult* r = same[i];
      p.problem_tre_mm.insert(p.problem_tre_mm.end(), r->problem_tre_mm.begin(), r->problem_tre_mm.end());
      p.problem_ms.insert(p.problem_ms.end(), r->problem_ms.begin(), r->problem_ms.end());
      if (judged) {
        p.problem_accepted.insert(p.problem_accepted.end(), r->problem_accepted.begin(), r->problem_accepted.end());
        p.problem_verdict_reason.insert(p.problem_verdict_reason.end(), r->problem_verdict_reason.begin(),
                                        r->problem_verdict_reason.end());
        p.verdict += tally_trade_verdict(*r, scene_of[i]->verdict_tolerance_mm);
      }
      const double w = 1.0 / double(same.size());
      p.memory_bytes += w * r->memory_bytes;
      p.precompute_s += w * r->precompute_s;
      p.ncc_vs_siddon += w * r->ncc_vs_siddon;
      p.psnr_db_vs_siddon += w * r->psnr_db_vs_siddon;
    }
    p.runs = int(p.problem_tre_mm.size());
    p.failed_runs = 0;
    p.failure.clear();
    for (const TradeResult* r : same)
      if (p.failure.empty() && !r->failure.empty()) p.failure = r->failure;
    std::vector<double> ms;
    double sum = 0;
    int ok = 0;
    for (std::size_t k = 0; k < p.problem_tre_mm.size(); ++k) {
      const bool ran = !std::isnan(p.problem_ms[k]);  // NaN: the registration failed
      if (ran) ms.push_back(p.problem_ms[k]);
      p.failed_runs += !ran;
      sum += p.problem_tre_mm[k];
      ok += ran && p.problem_tre_mm[k] < 2.0;
    }
    const double nan = std::numeric_limits<double>::quiet_NaN();
    p.median_ms = ms.empty() ? nan : quantile(ms, 0.5);
    p.p95_ms = ms.empty() ? nan : quantile(ms, 0.95);
    p.mean_tre_mm = sum / double(p.runs);
    p.p95_tre_mm = quantile(p.problem_tre_mm, 0.95);
    p.success_rate = double(ok) / double(p.runs);
    pooled.results.push_back(p);
  }
  for (const TradeStudy& s : scenes)
    for (const TradeResult& r : s.results)
      if (std::none_of(pooled.results.begin(), pooled.results.end(),
                       [&](const TradeResult& p) { return p.point.id == r.point.id; }))
        dropped.insert(r.point.id);
  if (left_out) left_out->assign(dropped.begin(), dropped.end());
  if (pooled.results.empty()) return failed_precondition("pool: the scenes have no point in common");
  pooled.points_total = int(pooled.results.size());
  pooled.shard = pooled.shards = 1;
  return pooled;
}

Status write_trade_outputs(const TradeStudy& study, const std::filesystem::path& dir) {
  LFTRACK_RETURN_IF_ERROR(write_trade_data(study, dir, false));
  const std::vector<TradeResult> front = pareto_front(study.results);

  ScatterPlot time_plot;
  time_plot.title = "Trade study, " + study.scene + ": TRE against registration time (" +
                    std::to_string(study.problems) + " problems per point)";
  time_plot.x_label = "median registration time (ms, log scale)";
  time_plot.y_label = "mean TRE (mm)";
  time_plot.log_x = true;
  for (const TradeResult& r : study.results)  // a failed point is listed under the front, not drawn
    if (!r.failed()) time_plot.points.push_back({r.median_ms, r.mean_tre_mm, r.point.id});
  for (const TradeResult& r : front) time_plot.front.push_back({r.median_ms, r.mean_tre_mm, r.point.id});
  auto drawn = draw_scatter_plot(time_plot, dir / "tre_vs_time.png");
  if (!drawn.ok()) return drawn.status();

  // Memory against fidelity; exact renderers (infinite PSNR) are listed in summary.md only.
  ScatterPlot memory_plot;
  memory_plot.title =
      "Trade study, " + study.scene + ": memory against DRR fidelity (exact renderers not shown)";
  memory_plot.x_label = "memory of the renderer's data (MB, log scale)";
  memory_plot.y_label = "PSNR of DRRs against Siddon (dB)";
  memory_plot.log_x = true;
  memory_plot.front_name = "least memory for its fidelity";
  memory_plot.key_position = "bottom right";
  std::vector<TradeResult> finite;
  for (const TradeResult& r : study.results)
    if (std::isfinite(r.psnr_db_vs_siddon) && r.memory_bytes > 0) finite.push_back(r);
  std::sort(finite.begin(), finite.end(),
            [](const TradeResult& a, const TradeResult& b) { return a.memory_bytes < b.memory_bytes; });
  double best_psnr = -1e300;
  for (const TradeResult& r : finite) {
    memory_plot.points.push_back({r.memory_bytes / 1e6, r.psnr_db_vs_siddon, r.point.id});
    if (r.psnr_db_vs_siddon > best_psnr) {
      best_psnr = r.psnr_db_vs_siddon;
      memory_plot.front.push_back({r.memory_bytes / 1e6, r.psnr_db_vs_siddon, r.point.id});
    }
  }
  auto drawn2 = draw_scatter_plot(memory_plot, dir / "memory_vs_fidelity.png");
  if (!drawn2.ok()) return drawn2.status();

  // What the loop would do with each point's results: the verdict's four outcomes, as rates with
  // their 95 % intervals and the count of results (an axis of rates alone).
  const std::string right = study.verdict_tolerance_mm > 0
                                ? "final mean TRE < " + fixed(study.verdict_tolerance_mm, 2) + " mm"
                                : "final mean TRE under each scene's safety.beam_tolerance_mm";
  std::vector<VerdictGroup> groups;
  for (const TradeResult& r : study.results)
    if (r.judged()) groups.push_back({r.point.id, r.verdict});
  GroupedBarChart verdict_chart =
      verdict_outcome_chart("Trade study, " + study.scene + ": the registration verdict against the truth (right: " +
                                right + ")",
                            groups);
  verdict_chart.width = std::max(1100, 110 * int(groups.size()));
  verdict_chart.slanted_categories = groups.size() > 6;
  verdict_chart.key_position = "outside right top";  // clear of the bars, however many points
  if (!groups.empty()) {
    auto drawn3 = draw_grouped_bars(verdict_chart, dir / "verdict.png");
    if (!drawn3.ok()) return drawn3.status();
  }

  nlohmann::json summary = {{"study", "trade"},
                            {"scene", study.scene},
                            {"problems", study.problems},
                            {"physics", study.physics},
                            {"success_threshold_mm", 2.0},
                            {"verdict_tolerance_mm", study.verdict_tolerance_mm},
                            {"points", nlohmann::json::array()}};
  for (const TradeResult& r : study.results) {
    const auto number = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); };
    summary["points"].push_back({{"id", r.point.id},
                                 {"settings", describe(r.point)},
                                 {"runs", r.runs},
                                 {"failed_runs", r.failed_runs},
                                 {"median_ms", number(r.median_ms)},
                                 {"p95_ms", number(r.p95_ms)},
                                 {"mean_tre_mm", number(r.mean_tre_mm)},
                                 {"p95_tre_mm", number(r.p95_tre_mm)},
                                 {"success_rate", r.success_rate},
                                 {"memory_bytes", r.memory_bytes},
                                 {"verdict", r.judged() ? verdict_outcomes_json(r.verdict) : nlohmann::json()}});
  }
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(dir / "summary.json", summary.dump(2) + "\n"));

  const TradeRecommendations rec = recommend(study.results);
  std::ostringstream md;
  md << "# Trade study: " << study.scene << "\n\n"
     << study.results.size() << " operating points" << (study.quick ? " (quick)" : "")
     << ", each registering the same " << study.problems << " problems (seed " << study.seed
     << "): gold poses within 0.4 x the scene's envelope, starts at an initial mean TRE of 1-4 mm, frames "
        "rendered by Siddon with noise"
     << (study.physics == "ideal" ? std::string()
                                  : " and " + study.physics + " physics (" + study.physics_description + ")")
     << ". Success: final mean TRE < 2 mm. Times are wall-clock on this host; "
        "compare them within one study.\n\n"
     << "![TRE against time](tre_vs_time.png)\n\n## Pareto front (mean TRE against median time)\n\n"
     << kTableHeader;
  for (const TradeResult& r : front) md << table_row(r);
  bool any_failed = false;
  for (const TradeResult& r : study.results)
    if (r.failed()) {
      if (!any_failed) md << "\nFailed points (on no front, never recommended):\n\n";
      any_failed = true;
      md << "- `" << r.point.id << "`: " << failure_text(r) << "\n";
    }
  md << "\n## Recommended defaults\n\n";
  auto line = [&](const char* what, bool has, const TradeResult& r) {
    md << "- **" << what << "**: ";
    if (!has) {
      md << "no point qualifies.\n";
      return;
    }
    md << "`" << r.point.id << "` (" << describe(r.point) << "): median " << fixed(r.median_ms, 1)
       << " ms, p95 " << fixed(r.p95_ms, 1) << " ms, mean TRE " << fixed(r.mean_tre_mm, 3) << " mm, memory "
       << mb(r.memory_bytes) << " MB.\n";
  };
  line("fastest within 1 mm mean TRE", rec.has_fastest, rec.fastest_within_1mm);
  line("most accurate within 100 ms p95 time", rec.has_accurate, rec.most_accurate_within_100ms);
  line("least memory within 0.5 mm mean TRE", rec.has_least_memory, rec.least_memory_within_half_mm);
  md << "\n(Each also needs a success rate of at least 95 % and no failed registration.)\n\n![memory against "
        "fidelity](memory_vs_fidelity.png)\n\n"
     << "## Every point\n\n"
     << kTableHeader;
  for (const TradeResult& r : study.results) md << table_row(r);
  md << "\n## The registration verdict\n\n"
     << "What the loop would do with each result: the verdict `lftrack register` and the loop use (the scene's "
        "limits for the point's measure, the check NCC against the point's renderer) against the truth (right: "
     << right << "; a failed registration is rejected and never right).\n\n"
     << (groups.empty() ? std::string() : "![the verdict per point](verdict.png)\n\n")
     << "| point | n | accepted, right | accepted, wrong (false accepts) | rejected, right (false rejects) | "
        "rejected, wrong |\n|---|---|---|---|---|---|\n";
  for (const TradeResult& r : study.results) md << verdict_row(r);
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(dir / "summary.md", md.str()));
  return write_trade_description(study, dir);  // last: the folder is now a complete result
}

}  // namespace lftrack::studies
