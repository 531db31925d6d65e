#pragma once
// The capture-range study (PAPERS.md, papers 1 and 2): start poses in bins of initial TRE
// (0-2, 2-4, ... mm), the same starts for every method, success when the final TRE is below
// 2.0 mm (paper 1) and 2.5 mm (paper 2). Every result is also judged by the registration verdict
// the loop and `register` use (the scene's, commissioned or default, for the method's measure),
// so the study reports what the loop would do with it: accepted and right, accepted but wrong
// (false accepts), rejected but right (false rejects), rejected and wrong.
//
// Gold poses are drawn inside the scene's envelope (one per sample index, with its own noisy
// synthetic frames); sample k of every bin starts from gold pose k perturbed along a random
// 6-D direction scaled (by bisection) to an initial mean TRE drawn uniformly in the bin.
//
// Sharded for a job array by gold sample: shard k of n registers the samples whose index is k-1
// modulo n, drawing the other samples' random numbers without rendering or registering, so each
// run is the run of the whole study. `lftrack study merge` joins the shards; several scenes'
// (patients') studies are pooled by concatenating their runs.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "lftrack/session/scene.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"

namespace lftrack::studies {

// "PLAN:MEASURE[+fiducial]", e.g. papers:mi, cmaes:mi, papers:mi+fiducial.
struct RegistrationMethod {
  std::string label;
  std::string plan = "papers";
  std::string similarity = "mi";
  bool fiducial = false;
};
Result<RegistrationMethod> parse_registration_method(const std::string& text);

struct CaptureRangeOptions {
  std::vector<RegistrationMethod> methods;
  int per_bin = 30;
  int bins = 8;
  double bin_width_mm = 2;
  double success_mm = 2.0;        // paper 1
  double success_loose_mm = 2.5;  // paper 2
  double gold_translation_mm = 3;  // gold poses: uniform within +-these of the nominal pose
  double gold_rotation_deg = 2;
  double max_start_rotation_deg = 10;  // start perturbations rotating more are redrawn
  std::uint64_t seed = 1;
  std::string renderer = "lightfield";
  std::filesystem::path light_field_dir;  // empty: the scene's default
  int shard = 1, shards = 1;              // register samples with index % shards == shard - 1
  // What the frames carry (issue 21): ideal DRRs of the planning CT, or realistic physics. With an
  // anatomy part, sample k images anatomy draw k % anatomy_draws (each draw a deformed patient);
  // with detector lag, each sample's frames follow an exposure at a pose 1 mm / 0.5 degrees away.
  sim_spec::XrayPhysicsSpec physics;
  std::string physics_name = "ideal";  // recorded with the study (and compared between shards)
  std::string physics_description;     // empty: sim_spec::describe(physics); a study read back has only this
  int anatomy_draws = 1;
};

// Gold samples shard `options.shard` registers.
int capture_range_shard_samples(const CaptureRangeOptions& options);

struct CaptureRangeRun {
  std::string method;
  int bin = 0;
  int sample = 0;
  double initial_tre_mm = 0;
  double tre_mean_mm = 0;
  double tre_max_mm = 0;
  bool success = false;        // tre_mean < success_mm
  bool success_loose = false;  // tre_mean < success_loose_mm
  bool accepted = false;       // the registration verdict accepted it
  int verdict_reason = 0;      // loop::VerdictReason's value (0: accepted)
  int evaluations = 0;
  double ms = 0;
};

struct CaptureRangeSummary {
  std::string name;
  double success_rate = 0;        // over every run, TRE < success_mm
  double success_rate_loose = 0;  // TRE < success_loose_mm
  double mean_tre_mm = 0;         // over successes
  double max_tre_mm = 0;          // over successes
  double capture_range_mm = 0;    // upper edge of the last bin of the run of bins from 0 with >= 95 % success
  double median_ms = 0;
  double p95_ms = 0;
  std::vector<double> bin_success_rate;
  // The verdict against success (right: TRE < success_mm), counts over every run.
  int accepted_right = 0, accepted_wrong = 0, rejected_right = 0, rejected_wrong = 0;
};

struct CaptureRangeReport {
  std::string scene;        // the scene's name; pooled reports: the names joined by " + "
  std::string fingerprint;  // study_scene_fingerprint of the scene; pooled: empty
  CaptureRangeOptions options;
  std::vector<CaptureRangeRun> runs;
  std::vector<CaptureRangeSummary> summaries;
};

// Runs every method on every start. `progress` gets the fraction done.
Result<CaptureRangeReport> run_capture_range_study(const session::PreparedScene& scene,
                                                   const CaptureRangeOptions& options,
                                                   tracking::ThreadPool* pool,
                                                   const std::function<void(double)>& progress = {});
// Summaries of a report's runs (also filled in by run_capture_range_study).
std::vector<CaptureRangeSummary> summarize_capture_range(const CaptureRangeOptions& options,
                                                         const std::vector<CaptureRangeRun>& runs);
// runs.csv, summary.json, capture_range.png (+ .dat, .gp) into `dir`.
Status write_capture_range_outputs(const CaptureRangeReport& report, const std::filesystem::path& dir);

// A shard's runs.csv and study.json (its options; written last, atomically) into `dir`. With
// `describe` false, study.json is left out (removed if there), for a writer with more to write.
Status write_capture_range_shard(const CaptureRangeReport& report, const std::filesystem::path& dir,
                                 bool describe = true);
// study.json alone: what makes a folder a complete result.
Status write_capture_range_description(const CaptureRangeReport& report, const std::filesystem::path& dir);
// Reads what write_capture_range_shard (or write_capture_range_outputs after it) wrote.
Result<CaptureRangeReport> read_capture_range_shard(const std::filesystem::path& dir);
// OK when `dir` holds the complete shard of the study `expected` describes (same scene and
// options, every run of its samples); otherwise why not.
Status check_capture_range_shard_complete(const std::filesystem::path& dir, const CaptureRangeReport& expected);
// Joins the shards of one study (refuses another study's shard, one given twice or missing).
Result<CaptureRangeReport> merge_capture_range_shards(const std::vector<CaptureRangeReport>& shards);
// Several scenes' whole studies as one: their runs together (samples renumbered after each
// other), summarised again. Refuses scenes given twice or studied with other options.
Result<CaptureRangeReport> pool_capture_range_reports(const std::vector<CaptureRangeReport>& scenes);

}  // namespace lftrack::studies
