#pragma once
// `lftrack bench drr`: every renderer, and plastimatch where installed, on the same poses and
// the same ROI-cropped detectors, in one run. Speeds are medians of single renders on the
// shared pool; fidelity is measured against the Siddon renderer at the same pose.

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "lftrack/session/scene.hpp"

namespace lftrack::studies {

struct DrrBenchOptions {
  int size = 256;            // DRR rows = cols; each detector's ROI window resampled to this
  int poses = 8;             // drawn uniformly across the scene's pose envelope
  int repeats = 3;           // timed renders per pose and view
  std::uint64_t seed = 7;    // pose sampling
  bool peers = true;         // run plastimatch if it is installed
  int render_threads = 1;    // threads for the timed renders (and plastimatch's OpenMP)
  bool light_fields = true;  // build the scene's light fields and time every storage mode
  std::vector<int> vq_codebooks{256, 4096, 65536};
  std::filesystem::path work_dir;  // for the peer's files; empty: a fresh temporary folder
  // Float light fields to load instead of building them (their precompute is then not timed);
  // empty: build them in the run.
  std::filesystem::path light_field_dir;
  // Also build the float fields with the other integration than the scene's (slices against the
  // exact walk), timed and measured as one more renderer, "lightfield-float-slices" (or
  // "-siddon"); needs the fields built in the run (no light_field_dir).
  bool both_integrations = false;
};

struct RendererFigures {
  std::string name;
  double ms_median = 0;
  double ms_min = 0;                  // fastest render: less disturbed by other load on a shared machine
  double ncc_vs_siddon = 0;           // mean over poses and views
  double ncc_min_vs_siddon = 0;       // worst pose and view
  double psnr_db_vs_siddon = 0;       // mean over poses and views (inf for Siddon itself)
  double speedup_vs_siddon = 0;       // Siddon's median time / this one's
  double speedup_vs_plastimatch = 0;  // plastimatch's median time / this one's
  // Light fields: the median over poses and views of plastimatch's time / this renderer's,
  // each renderer timed right after each plastimatch run, so both see the same machine load.
  double speedup_vs_plastimatch_side_by_side = 0;
  std::size_t bytes = 0;             // precomputed data held (light fields, all views)
  double out_of_field_fraction = 0;  // masked pixels / all pixels
  double precompute_s = 0;           // light fields: building (all views) and converting
};

struct PeerFigures {
  std::string name;
  double ms_median = 0;       // the peer's own render time (no volume loading)
  double ms_wall_median = 0;  // whole process, volume loading included
  double ncc_vs_siddon = 0;
  double ncc_min_vs_siddon = 0;
  double max_abs_diff_rel = 0;  // max |peer - siddon| / max(siddon), worst image
};

struct DrrBenchReport {
  std::string ct;
  int rows = 0, cols = 0;
  int threads = 1;
  int render_threads = 1;
  double precompute_s = 0;  // building the float light fields of all views (0: loaded)
  std::string integration;  // how those were integrated (the scene's tracking.light_field.integration)
  std::string other_integration;  // both_integrations: the other way, and its precompute (0: not built)
  double other_precompute_s = 0;
  std::array<int, 4> light_field_resolution{};
  int poses = 0;
  std::vector<std::string> views;
  std::vector<RendererFigures> renderers;
  std::vector<PeerFigures> peers;
  std::string peer_note;  // why there are no peers, if there are none
};

// `count` poses T_room_from_ct = apply_delta(nominal, delta) with delta uniform in the
// envelope (each translation component in +-translation_mm, each rotation-vector component in
// +-rotation_deg), about the registration origin. The first pose is the nominal one.
std::vector<tracking::Pose> sample_envelope_poses(const session::PreparedScene& scene, int count,
                                                  std::uint64_t seed);

// Each detector's ROI window resampled to size x size pixels (room frame).
std::vector<tracking::XrayView> roi_views(const session::PreparedScene& scene, int size);

Result<DrrBenchReport> run_drr_benchmark(const session::PreparedScene& scene, const DrrBenchOptions& options,
                                         tracking::ThreadPool* pool);

nlohmann::json to_json(const DrrBenchReport& report);

}  // namespace lftrack::studies
