#pragma once
// The realism study (issue 21): what each part of the imaging physics costs the registration.
// The capture-range study is run once per factor set: `ideal` (DRRs of the planning CT), each
// part of the scene's realistic physics alone (its sim.physics when it has any, else the clinical
// preset; the anatomy split into soft tissue, adjacent vertebrae and breathing where the scene
// breathes), and all of it together (`clinical`). Every set sees the same gold poses, starts and
// photon noise; the anatomy sets see the same anatomy draws.
//
// Per set: mean TRE of successes and success rate of the image-only method for starts up to
// `image_max_mm` initial mean TRE, the hybrid method's (one fiducial) success up to
// `hybrid_max_mm`, and the median registration time.

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "lftrack/studies/capture_range_study.hpp"

namespace lftrack::studies {

struct RealismFactor {
  std::string name;
  sim_spec::XrayPhysicsSpec physics;
};
// The factor sets of `scene`, in report order.
std::vector<RealismFactor> realism_factors(const session::PreparedScene& scene);

struct RealismOptions {
  int per_bin = 20;       // gold poses (each with one start per 2 mm bin)
  int bins = 8;           // 0-16 mm
  int anatomy_draws = 5;  // deformed patients, shared by the gold poses in turn
  double image_max_mm = 10;
  double hybrid_max_mm = 16;
  std::uint64_t seed = 1;
  std::string renderer = "lightfield";
  std::filesystem::path light_field_dir;
  int shard = 1, shards = 1;
  std::vector<std::string> only;  // factor sets to run (empty: all)
  static RealismOptions quick();  // the --quick study: 4 gold poses, 2 anatomy draws
};

struct RealismFactorSummary {
  std::string name;
  std::string physics;      // sim_spec::describe
  double mean_tre_mm = 0;   // image-only successes, starts <= image_max_mm
  double success_rate = 0;  // image-only, starts <= image_max_mm
  double median_ms = 0;     // image-only
  double p95_tre_mm = 0;    // image-only successes
  double sd_tre_mm = 0;     // image-only successes: their standard deviation
  // Image-only runs judged by the registration verdict against success (capture_range_study.hpp).
  int accepted_right = 0, accepted_wrong = 0, rejected_right = 0, rejected_wrong = 0;
  int successes = 0;
  double hybrid_success_rate = -1;  // starts <= hybrid_max_mm; -1 without a fiducial
  double hybrid_mean_tre_mm = 0;
  int runs = 0;
};

struct RealismReport {
  std::string scene;        // pooled reports: the names joined by " + "
  std::string fingerprint;  // study_scene_fingerprint of the scene; pooled: empty
  RealismOptions options;
  std::string image_method, hybrid_method;  // hybrid: empty without a fiducial
  std::vector<CaptureRangeReport> studies;  // per factor set (physics_name = the set's name)
  std::vector<RealismFactorSummary> factors;
};

// The capture-range options of factor set `factor`.
CaptureRangeOptions realism_capture_range_options(const session::PreparedScene& scene,
                                                  const RealismOptions& options, const RealismFactor& factor);

// The factor sets `options.only` selects (all when empty), in report order; names that are not a
// set of this scene are refused, with the scene's sets.
Result<std::vector<RealismFactor>> selected_realism_factors(const session::PreparedScene& scene,
                                                            const RealismOptions& options);

Result<RealismReport> run_realism_study(const session::PreparedScene& scene, const RealismOptions& options,
                                        tracking::ThreadPool* pool,
                                        const std::function<void(double)>& progress = {});
RealismFactorSummary summarize_realism_factor(const RealismOptions& options, const CaptureRangeReport& study,
                                              const std::string& image_method, const std::string& hybrid_method);
// DIR/<set>/ (each set's capture-range outputs, or its shard), and for a whole study
// DIR/summary.json (`factors`: name, mean_tre_mm, success_rate, median_ms, ...), DIR/realism.csv,
// DIR/realism_tre.png (TRE per set, mean and SD) and DIR/realism_rates.png (success and the
// verdict's false accepts and false rejects per set, with 95 % intervals); for a shard, DIR/study.json (see write_realism_description).
Status write_realism_outputs(const RealismReport& report, const std::filesystem::path& dir);

// ---- Shards (issue 25; realism_shards.cpp) ----
// A realism shard is a folder with each factor set's capture-range shard in DIR/<set>/ and, written
// last, DIR/study.json: the scene, its fingerprint, the options, the methods and the sets. Without
// study.json the folder is not a result.
Status write_realism_description(const RealismReport& report, const std::filesystem::path& dir);
// Reads a shard back (each set's runs from its folder, summarised); refuses a folder whose sets do
// not match its description.
Result<RealismReport> read_realism_shard(const std::filesystem::path& dir);
// What shard `options.shard` of `scene`'s study holds when complete: the description and each
// set's capture-range options, without runs.
Result<RealismReport> expected_realism_shard(const session::PreparedScene& scene,
                                             const RealismOptions& options);
// OK when `dir` holds the complete shard `expected` describes (every set with every run);
// kFailedPrecondition when it holds another study's; otherwise why not.
Status check_realism_shard_complete(const std::filesystem::path& dir, const RealismReport& expected);
// Joins the shards of one scene's study into the whole study (refuses another study's shard, one
// given twice, or a missing one).
Result<RealismReport> merge_realism_shards(const std::vector<RealismReport>& shards);
// Several scenes' whole studies as one, per factor set (each set's runs pooled as the
// capture-range study pools them). Refuses scenes with other options, methods or sets.
Result<RealismReport> pool_realism_reports(const std::vector<RealismReport>& scenes);

}  // namespace lftrack::studies
