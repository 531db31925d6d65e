#pragma once
// `lftrack bench octree`: paper 3's table for a CT. For each pivot P: the leaves ("cells"), the
// compression (fewer cells than voxels, %), memory, the time to compress, the octree DRR's time
// against the Siddon DRR of the uncompressed volume, and its fidelity (NCC, PSNR) against that DRR.
//
// The DRRs cover the whole CT, as in the paper: two views (lateral and anterior-posterior),
// source 1.5 m and detector 1 m from the CT's centre, square detectors just covering the CT's
// projection, at poses within +-5 mm and +-5 degrees of the CT's own frame. Renders are
// single-threaded; Siddon and every octree render the same poses in one run.

#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::studies {

struct OctreeBenchOptions {
  std::vector<double> pivots{0, 0.001, 0.01, 0.02, 0.07, 0.2, 0.7};  // the paper's
  int size = 256;                                                    // DRR rows = cols
  int poses = 3;                                                     // per view
  int repeats = 2;                                                   // timed renders per pose and view
  std::uint64_t seed = 5;                                            // pose sampling
};

struct OctreeBenchRow {
  double pivot = 0;
  double threshold_per_mm = 0;
  std::size_t cells = 0;           // leaves
  double compression_percent = 0;  // 100 (1 - cells / voxels)
  std::size_t list_bytes = 0;      // the ordered (size, value) list
  std::size_t render_bytes = 0;    // the traversal layout the renderer holds
  double build_s = 0;
  double max_voxel_error_per_mm = 0;  // decompressed against the original
  double ms_median = 0;               // one octree DRR
  double speedup_vs_siddon = 0;       // Siddon's median / this one's
  double ncc_vs_uncompressed = 0;     // mean over poses and views
  double ncc_min_vs_uncompressed = 0;
  double psnr_db_vs_uncompressed = 0;  // mean
};

struct OctreeBenchReport {
  std::string ct;
  std::int64_t voxels = 0;
  std::size_t volume_bytes = 0;  // the uncompressed float volume
  int rows = 0, cols = 0, poses = 0;
  double siddon_ms_median = 0;
  std::vector<OctreeBenchRow> rows_by_pivot;
};

// The two whole-CT views of `size` x `size` pixels.
std::vector<tracking::XrayView> whole_volume_views(const tracking::VolumeGeometry& geometry, int size);

// `progress` gets the fraction done.
Result<OctreeBenchReport> run_octree_benchmark(const tracking::MuVolume& volume, const std::string& ct_name,
                                               const OctreeBenchOptions& options,
                                               const std::function<void(double)>& progress = {});
nlohmann::json to_json(const OctreeBenchReport& report);

}  // namespace lftrack::studies
