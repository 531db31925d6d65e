#pragma once
// `lftrack study sensitivity` (issue 8): how much a calibration error costs in TRE. Frames are
// synthesised with the scene's (true) geometry; the registration uses a model geometry with one
// error put in (source moved, detector tilted, pitch off, ...). The same gold poses, starts and
// noise serve every case, so the difference to the error-free case is the error's own effect.
// DRRs inside the registration are ray-cast (Siddon): a light field would have to be rebuilt for
// every perturbed geometry.
//
// Every result is also judged by the registration verdict the loop and `register` use (the
// scene's limits for its measure, scene_verdict_limits; the image-quality gate, preprocessing and
// the check NCC with the model geometry, all the system knows), as `study capture-range` judges
// its runs: per case, the four outcomes against the truth (verdict_outcomes.hpp; right: mean TRE
// against gold under the scene's safety.beam_tolerance_mm). A calibration error the verdict does
// not see is a false accept once it costs more than the tolerance.

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "lftrack/session/scene.hpp"
#include "lftrack/studies/verdict_outcomes.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::studies {

struct SensitivityOptions {
  int runs = 6;             // registrations per case
  double start_tre_mm = 2;  // starts this far (mean TRE) from gold
  std::string plan = "quadratic";
  std::uint64_t seed = 1;
};

struct SensitivityCase {
  std::string key;         // short, for files and plots: "no-error", "source-across", ...
  std::string name;        // e.g. "source A +1 mm along the beam"
  double mean_tre_mm = 0;  // against gold
  double max_tre_mm = 0;
  double mean_added_mm = 0;  // mean TRE between this case's result and the error-free case's
  VerdictOutcomes verdict;   // the registration verdict against the truth, over the case's runs
  // Per run, in the problems' order: TRE against gold, TRE added (against the error-free case's
  // result), whether the verdict accepted it and VerdictReason's value (0: accepted).
  std::vector<double> run_tre_mm, run_added_mm;
  std::vector<int> run_accepted, run_verdict_reason;
};

struct SensitivityReport {
  std::string scene, plan;
  int runs = 0;
  std::string measure;              // the scene's similarity, whose verdict judges the results
  double verdict_tolerance_mm = 2;  // right: TRE under this (the scene's safety.beam_tolerance_mm)
  std::vector<SensitivityCase> cases;  // first: no error
};

Result<SensitivityReport> run_geometry_sensitivity(const session::PreparedScene& scene,
                                                   const SensitivityOptions& options,
                                                   tracking::ThreadPool* pool);
nlohmann::json to_json(const SensitivityReport& report);
// runs.csv (one row per case and run, with accepted and verdict_reason as capture-range's),
// summary.json (to_json) and verdict.png (the verdict's four outcomes per case, 95 % intervals;
// + .dat, .gp) in `dir`.
Status write_sensitivity_outputs(const SensitivityReport& report, const std::filesystem::path& dir);

}  // namespace lftrack::studies
