#include "lftrack/studies/realism_study.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "lftrack/studies/plot.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "quantile.hpp"

namespace lftrack::studies {

using session::PreparedScene;

RealismOptions RealismOptions::quick() {
  RealismOptions o;
  o.per_bin = 4;
  o.anatomy_draws = 2;
  return o;
}

std::vector<RealismFactor> realism_factors(const PreparedScene& p) {
  const sim_spec::XrayPhysicsSpec all =
      p.scene.sim.physics.ideal() ? sim_spec::clinical_physics() : p.scene.sim.physics;
  std::vector<RealismFactor> out;
  auto add = [&](const std::string& name, auto set_part) {
    RealismFactor f;
    f.name = name;
    set_part(f.physics);
    out.push_back(std::move(f));
  };
  add("ideal", [](sim_spec::XrayPhysicsSpec&) {});
  if (all.spectrum) add("spectrum", [&](sim_spec::XrayPhysicsSpec& s) { s.spectrum = all.spectrum; });
  if (all.scatter) add("scatter", [&](sim_spec::XrayPhysicsSpec& s) { s.scatter = all.scatter; });
  if (all.detector) add("detector", [&](sim_spec::XrayPhysicsSpec& s) { s.detector = all.detector; });
  if (all.anatomy) {
    const sim_spec::AnatomySpec a = *all.anatomy;
    if (a.soft_tissue_mm > 0)
      add("soft_tissue", [&](sim_spec::XrayPhysicsSpec& s) {
        s.anatomy = a;
        s.anatomy->adjacent_translation_mm = s.anatomy->adjacent_rotation_deg = s.anatomy->breathing_mm = 0;
      });
    if (a.adjacent_translation_mm > 0 || a.adjacent_rotation_deg > 0)
      add("adjacent_vertebrae", [&](sim_spec::XrayPhysicsSpec& s) {
        s.anatomy = a;
        s.anatomy->soft_tissue_mm = s.anatomy->breathing_mm = 0;
      });
    if (a.breathing_mm > 0)
      add("breathing", [&](sim_spec::XrayPhysicsSpec& s) {
        s.anatomy = a;
        s.anatomy->soft_tissue_mm = s.anatomy->adjacent_translation_mm = s.anatomy->adjacent_rotation_deg = 0;
      });
  }
  add("clinical", [&](sim_spec::XrayPhysicsSpec& s) { s = all; });
  return out;
}

namespace {
std::string image_method_of(const PreparedScene& p) { return p.scene.registration.plan + ":" + p.scene.registration.similarity; }
std::string hybrid_method_of(const PreparedScene& p) {
  return p.scene.fiducials.positions_ct_mm.empty() ? "" : image_method_of(p) + "+fiducial";
}
}  // namespace

CaptureRangeOptions realism_capture_range_options(const PreparedScene& p, const RealismOptions& o,
                                                  const RealismFactor& factor) {
  CaptureRangeOptions c;
  c.methods.push_back(*parse_registration_method(image_method_of(p)));
  if (!hybrid_method_of(p).empty()) c.methods.push_back(*parse_registration_method(hybrid_method_of(p)));
  c.per_bin = o.per_bin;
  c.bins = o.bins;
  c.seed = o.seed;
  c.renderer = o.renderer;
  c.light_field_dir = o.light_field_dir;
  c.shard = o.shard;
  c.shards = o.shards;
  c.physics = factor.physics;
  c.physics_name = factor.name;
  c.anatomy_draws = std::max(1, std::min(o.anatomy_draws, o.per_bin));
  return c;
}

RealismFactorSummary summarize_realism_factor(const RealismOptions& o, const CaptureRangeReport& study,
                                              const std::string& image_method, const std::string& hybrid_method) {
  RealismFactorSummary s;
  s.name = study.options.physics_name;
  s.physics = study.options.physics_description.empty() ? sim_spec::describe(study.options.physics)
                                                        : study.options.physics_description;
  std::vector<double> tre, ms;
  int image_runs = 0, image_ok = 0, hybrid_runs = 0, hybrid_ok = 0;
  double hybrid_sum = 0;
  for (const CaptureRangeRun& r : study.runs) {
    if (r.method == image_method && r.initial_tre_mm <= o.image_max_mm) {
      ++image_runs;
      ms.push_back(r.ms);
      (r.accepted ? (r.success ? s.accepted_right : s.accepted_wrong) : (r.success ? s.rejected_right : s.rejected_wrong))++;
      if (r.success) {
        ++image_ok;
        tre.push_back(r.tre_mean_mm);
      }
    } else if (!hybrid_method.empty() && r.method == hybrid_method && r.initial_tre_mm <= o.hybrid_max_mm) {
      ++hybrid_runs;
      if (r.success) {
        ++hybrid_ok;
        hybrid_sum += r.tre_mean_mm;
      }
    }
  }
  s.runs = image_runs;
  s.success_rate = image_runs ? double(image_ok) / image_runs : 0;
  double sum = 0;
  for (double t : tre) sum += t;
  s.mean_tre_mm = tre.empty() ? 0 : sum / double(tre.size());
  double squares = 0;
  for (double t : tre) squares += (t - s.mean_tre_mm) * (t - s.mean_tre_mm);
  s.sd_tre_mm = tre.size() > 1 ? std::sqrt(squares / double(tre.size() - 1)) : 0;
  s.successes = image_ok;
  s.p95_tre_mm = quantile(tre, 0.95);
  s.median_ms = quantile(ms, 0.5);
  if (!hybrid_method.empty()) {
    s.hybrid_success_rate = hybrid_runs ? double(hybrid_ok) / hybrid_runs : 0;
    s.hybrid_mean_tre_mm = hybrid_ok ? hybrid_sum / hybrid_ok : 0;
  }
  return s;
}

Result<std::vector<RealismFactor>> selected_realism_factors(const PreparedScene& p, const RealismOptions& o) {
  const std::vector<RealismFactor> all = realism_factors(p);
  std::string known;
  for (const RealismFactor& f : all) known += (known.empty() ? "" : ", ") + f.name;
  for (const std::string& name : o.only)
    if (std::none_of(all.begin(), all.end(), [&](const RealismFactor& f) { return f.name == name; }))
      return invalid_argument("realism: --only names '" + name + "', not a factor set of this scene (" + known + ")");
  std::vector<RealismFactor> factors;
  for (const RealismFactor& f : all)
    if (o.only.empty() || std::find(o.only.begin(), o.only.end(), f.name) != o.only.end()) factors.push_back(f);
  return factors;
}

namespace {

// What a realism report says of its study before any run: the scene, options and methods.
RealismReport realism_report_of(const PreparedScene& p, const RealismOptions& o) {
  RealismReport report;
  report.scene = p.scene.name;
  report.fingerprint = study_scene_fingerprint(p);
  report.options = o;
  report.image_method = image_method_of(p);
  report.hybrid_method = hybrid_method_of(p);
  return report;
}

}  // namespace

Result<RealismReport> run_realism_study(const PreparedScene& p, const RealismOptions& o, tracking::ThreadPool* pool,
                                        const std::function<void(double)>& progress) {
  RealismReport report = realism_report_of(p, o);
  auto factors = selected_realism_factors(p, o);
  if (!factors.ok()) return factors.status();
  for (std::size_t i = 0; i < factors->size(); ++i) {
    const RealismFactor& factor = (*factors)[i];
    spdlog::info("realism: {} ({})", factor.name, sim_spec::describe(factor.physics));
    auto study = run_capture_range_study(p, realism_capture_range_options(p, o, factor), pool, [&](double f) {
      if (progress) progress((double(i) + f) / double(factors->size()));
    });
    if (!study.ok()) return study.status().with_context("factor set " + factor.name);
    report.factors.push_back(summarize_realism_factor(o, *study, report.image_method, report.hybrid_method));
    report.studies.push_back(std::move(study).value());
  }
  return report;
}

Result<RealismReport> expected_realism_shard(const PreparedScene& p, const RealismOptions& o) {
  RealismReport report = realism_report_of(p, o);
  auto factors = selected_realism_factors(p, o);
  if (!factors.ok()) return factors.status();
  for (const RealismFactor& factor : *factors) {
    CaptureRangeReport study;
    study.scene = report.scene;
    study.fingerprint = report.fingerprint;
    study.options = realism_capture_range_options(p, o, factor);
    report.studies.push_back(std::move(study));
  }
  return report;
}

Status write_realism_outputs(const RealismReport& report, const std::filesystem::path& dir) {
  const RealismOptions& o = report.options;
  if (o.shards > 1) {
    // An earlier description goes first: a folder being rewritten never reads as a result.
    std::error_code ec;
    std::filesystem::remove(dir / "study.json", ec);
    if (ec) return io_error((dir / "study.json").string() + ": cannot remove the earlier description");
  }
  for (const CaptureRangeReport& study : report.studies) {
    const auto sub = dir / study.options.physics_name;
    if (o.shards > 1)
      LFTRACK_RETURN_IF_ERROR(write_capture_range_shard(study, sub));
    else
      LFTRACK_RETURN_IF_ERROR(write_capture_range_outputs(study, sub));
  }
  if (o.shards > 1) return write_realism_description(report, dir);  // last: the shard is complete
  nlohmann::json j;
  j["study"] = "realism";
  j["scene"] = report.scene;
  j["fingerprint"] = report.fingerprint;
  j["seed"] = o.seed;
  j["image_method"] = report.image_method;
  j["hybrid_method"] = report.hybrid_method;
  j["image_starts_up_to_mm"] = o.image_max_mm;
  j["hybrid_starts_up_to_mm"] = o.hybrid_max_mm;
  j["gold_poses"] = o.per_bin;
  j["anatomy_draws"] = o.anatomy_draws;
  j["renderer"] = o.renderer;
  j["factors"] = nlohmann::json::array();
  std::string csv = "factor,mean_tre_mm,p95_tre_mm,success_rate,median_ms,hybrid_success_rate,hybrid_mean_tre_mm,runs,physics\n";
  for (const RealismFactorSummary& f : report.factors) {
    nlohmann::json e = {{"name", f.name},
                        {"physics", f.physics},
                        {"mean_tre_mm", f.mean_tre_mm},
                        {"p95_tre_mm", f.p95_tre_mm},
                        {"success_rate", f.success_rate},
                        {"median_ms", f.median_ms},
                        {"runs", f.runs},
                        {"sd_tre_mm", f.sd_tre_mm},
                        {"verdict", {{"accepted_right", f.accepted_right},
                                     {"false_accepts", f.accepted_wrong},
                                     {"false_rejects", f.rejected_right},
                                     {"rejected_wrong", f.rejected_wrong}}}};
    if (f.hybrid_success_rate >= 0) {
      e["hybrid_success_rate"] = f.hybrid_success_rate;
      e["hybrid_mean_tre_mm"] = f.hybrid_mean_tre_mm;
    }
    j["factors"].push_back(e);
    char line[512];
    std::snprintf(line, sizeof line, "%s,%.4f,%.4f,%.4f,%.2f,%.4f,%.4f,%d,\"%s\"\n", f.name.c_str(), f.mean_tre_mm,
                  f.p95_tre_mm, f.success_rate, f.median_ms, f.hybrid_success_rate, f.hybrid_mean_tre_mm, f.runs,
                  f.physics.c_str());
    csv += line;
  }
  LFTRACK_RETURN_IF_ERROR(write_file_atomically(dir / "realism.csv", csv));
  // Categories as bars, millimetres and rates each on an axis of their own, with their spread
  // and the count of runs.
  const std::string starts = " (starts <= " + std::to_string(int(o.image_max_mm)) + " mm)";
  GroupedBarChart tre_chart, rate_chart;
  tre_chart.title = report.scene + ": " + report.image_method + " TRE of successes per physics factor" + starts;
  tre_chart.y_label = "mean TRE of successes (mm), bars +- 1 SD";
  rate_chart.title = report.scene + ": " + report.image_method + " per physics factor" + starts;
  rate_chart.y_label = "runs (%), bars: 95 % interval";
  rate_chart.y_min = 0;
  rate_chart.y_max = 105;
  BarSeries tre{"image only", {}, {}, {}}, hybrid{"hybrid (one fiducial), starts <= " +
                                                      std::to_string(int(o.hybrid_max_mm)) + " mm (mean only)", {}, {}, {}};
  BarSeries success{"success (TRE < 2 mm)", {}, {}, {}}, false_accepts{"verdict: false accepts", {}, {}, {}},
      false_rejects{"verdict: false rejects", {}, {}, {}};
  for (const RealismFactorSummary& f : report.factors) {
    const std::string category = f.name + " (n=" + std::to_string(f.runs) + ")";
    tre_chart.categories.push_back(category);
    rate_chart.categories.push_back(category);
    tre.value.push_back(f.mean_tre_mm);
    tre.low.push_back(std::max(0.0, f.mean_tre_mm - f.sd_tre_mm));
    tre.high.push_back(f.mean_tre_mm + f.sd_tre_mm);
    hybrid.value.push_back(f.hybrid_success_rate > 0 ? f.hybrid_mean_tre_mm : 0);
    const auto add = [&](BarSeries* s, int k) {
      const auto [lo, hi] = wilson_interval(k, f.runs);
      s->value.push_back(f.runs ? 100.0 * k / f.runs : 0);
      s->low.push_back(100 * lo);
      s->high.push_back(100 * hi);
    };
    add(&success, f.successes);
    add(&false_accepts, f.accepted_wrong);
    add(&false_rejects, f.rejected_right);
  }
  tre_chart.series = {tre};
  if (!report.hybrid_method.empty()) tre_chart.series.push_back(hybrid);
  rate_chart.series = {success, false_accepts, false_rejects};
  if (auto drawn = draw_grouped_bars(tre_chart, dir / "realism_tre.png"); !drawn.ok()) return drawn.status();
  if (auto drawn = draw_grouped_bars(rate_chart, dir / "realism_rates.png"); !drawn.ok()) return drawn.status();
  return write_file_atomically(dir / "summary.json", j.dump(2) + "\n");  // last: the folder is complete
}

}  // namespace lftrack::studies
