#pragma once
// `lftrack bench frames` (issue 51): the simulator's frame pairs rendered by Siddon and by light
// fields, side by side in one run, each exactly as the simulated loop's detectors render them:
// the scene's physics (ideal, or the realistic preset's water and bone with scatter, lag and the
// detector's fixed pattern), one thread (the detectors' render thread), both views one after the
// other. Speed is the time of a whole pair; fidelity is each light-field frame's expected counts
// (no photon noise) against Siddon's at the same pose, over the ROI window, each exposed as the
// loop exposes it. Each pair is timed twice, side by side: the ROI windows alone, and the whole
// detectors the loop now exposes (the rest of each detector rendered coarser, by Siddon).

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "lftrack/session/scene.hpp"

namespace lftrack::studies {

struct FrameBenchOptions {
  int pairs = 20;           // timed pairs per renderer, at poses drawn across the envelope
  std::uint64_t seed = 11;  // pose sampling and photon noise
  // Where the simulator's light fields are (and are built when missing): the scene's default
  // folder when empty, as `lftrack sim` uses it.
  std::filesystem::path light_field_dir;
};

struct FrameRendererFigures {
  std::string renderer;         // "siddon" or "lightfield"
  double setup_s = 0;           // the patient's volumes and the renderers (light fields loaded or built)
  // Pixels rendered per pair: each ROI window grown by the loop's margin for this renderer (16 for
  // Siddon; none for a light field, which covers the ROI only).
  int exposed_pixels = 0;
  double pair_ms_median = 0;    // one frame pair, both views
  double pair_ms_p95 = 0;
  double pair_ms_min = 0;
  // The whole detectors as the loop exposes them: the windows above and the rest of each
  // detector, coarser (surround_frames.hpp); pixels written per pair, and the pair's time.
  std::int64_t whole_detector_pixels = 0;
  double whole_pair_ms_median = 0;
  double whole_pair_ms_p95 = 0;
  double speedup_vs_siddon = 0; // Siddon's median pair time / this one's
  // Expected counts over the ROI windows against Siddon's, each as the loop exposes them (its
  // margin: scatter and glare see the exposed window); mean over poses and views, and the worst
  // (NaN where a frame held a non-finite count). 1 for Siddon, the reference.
  double ncc_vs_siddon = 0;
  double ncc_min_vs_siddon = 0;
};

struct FrameBenchReport {
  std::string scene;
  std::string physics;  // the scene's sim.physics, one line per part that is on (sim_spec::describe)
  int pairs = 0;
  std::vector<std::string> views;
  std::vector<FrameRendererFigures> renderers;
};

// Siddon first, then light fields (built into the light-field folder if missing, before any
// timing). The scene's own sim.renderer does not matter: both are measured.
Result<FrameBenchReport> run_frame_benchmark(const session::PreparedScene& scene,
                                             const FrameBenchOptions& options, tracking::ThreadPool* pool);

nlohmann::json to_json(const FrameBenchReport& report);

}  // namespace lftrack::studies
