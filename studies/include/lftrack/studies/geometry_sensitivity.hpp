#pragma once
// `lftrack study sensitivity` (issue 8): how much a calibration error costs in TRE. Frames are
// synthesised with the scene's (true) geometry; the registration uses a model geometry with one
// error put in (source moved, detector tilted, pitch off, ...). The same gold poses, starts and
// noise serve every case, so the difference to the error-free case is the error's own effect.
// DRRs inside the registration are ray-cast (Siddon): a light field would have to be rebuilt for
// every perturbed geometry.

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "lftrack/host/scene.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::host {

struct SensitivityOptions {
  int runs = 6;             // registrations per case
  double start_tre_mm = 2;  // starts this far (mean TRE) from gold
  std::string plan = "quadratic";
  std::uint64_t seed = 1;
};

struct SensitivityCase {
  std::string name;        // e.g. "source A +1 mm along the beam"
  double mean_tre_mm = 0;  // against gold
  double max_tre_mm = 0;
  double mean_added_mm = 0;  // mean TRE between this case's result and the error-free case's
};

struct SensitivityReport {
  std::string scene, plan;
  int runs = 0;
  std::vector<SensitivityCase> cases;  // first: no error
};

Result<SensitivityReport> run_geometry_sensitivity(const PreparedScene& scene,
                                                   const SensitivityOptions& options,
                                                   tracking::ThreadPool* pool);
nlohmann::json to_json(const SensitivityReport& report);

}  // namespace lftrack::host
