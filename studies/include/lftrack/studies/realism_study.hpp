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

namespace lftrack::host {

struct RealismFactor {
  std::string name;
  sim::XrayPhysicsSpec physics;
};
// The factor sets of `scene`, in report order.
std::vector<RealismFactor> realism_factors(const PreparedScene& scene);

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
  std::string physics;    // sim::describe
  double mean_tre_mm = 0;   // image-only successes, starts <= image_max_mm
  double success_rate = 0;  // image-only, starts <= image_max_mm
  double median_ms = 0;     // image-only
  double p95_tre_mm = 0;    // image-only successes
  double hybrid_success_rate = -1;  // starts <= hybrid_max_mm; -1 without a fiducial
  double hybrid_mean_tre_mm = 0;
  int runs = 0;
};

struct RealismReport {
  std::string scene;
  RealismOptions options;
  std::string image_method, hybrid_method;  // hybrid: empty without a fiducial
  std::vector<CaptureRangeReport> studies;  // per factor set (physics_name = the set's name)
  std::vector<RealismFactorSummary> factors;
};

// The capture-range options of factor set `factor`.
CaptureRangeOptions realism_capture_range_options(const PreparedScene& scene, const RealismOptions& options,
                                                  const RealismFactor& factor);

Result<RealismReport> run_realism_study(const PreparedScene& scene, const RealismOptions& options,
                                        tracking::ThreadPool* pool, const std::function<void(double)>& progress = {});
RealismFactorSummary summarize_realism_factor(const RealismOptions& options, const CaptureRangeReport& study,
                                              const std::string& image_method, const std::string& hybrid_method);
// DIR/<set>/ (each set's capture-range outputs, or its shard), and for a whole study
// DIR/summary.json (`factors`: name, mean_tre_mm, success_rate, median_ms, ...), DIR/realism.csv,
// DIR/realism.png.
Status write_realism_outputs(const RealismReport& report, const std::filesystem::path& dir);

}  // namespace lftrack::host
