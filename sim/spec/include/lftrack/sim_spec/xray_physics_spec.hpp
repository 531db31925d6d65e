#pragma once
// The imaging physics a scene asks of its synthetic frames (scene section `sim.physics`; DESIGN.md
// "Simulated imaging physics"; issue 21), as data. Each part is optional; none at all is the
// `ideal` preset: mono-energetic DRRs of the planning CT with photon noise, detector blur and
// quantisation. `clinical` switches every part on at typical values. The models that act on
// each part, and the sources of the typical values, are the simulator's: xray_spectrum.hpp,
// scatter_model.hpp, detector_effects.hpp and anatomy_deformation.hpp in lftrack/sim.

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"

namespace lftrack::sim_spec {

// More photons per pixel than this is no X-ray detector (a 16-bit panel saturates far below it):
// the most a scene's `sim.photons_per_pixel` and the simulator's detector model may ask
// (sim::check_detector_model). Here, beside the physics, because the scene parser checks it.
inline constexpr double kMaxPhotonsPerPixel = 1e9;

// The beam: a tungsten anode's bremsstrahlung at `kvp` through `filtration_mm_al` of aluminium
// (inherent plus added), in bins of `bin_kev` from 10 keV to the kVp (sim::make_spectrum).
struct SpectrumSpec {
  double kvp = 120;
  double filtration_mm_al = 2.5;
  double bin_kev = 1;
};

struct BeamSpec {
  SpectrumSpec spectrum;
  // The planning CT's effective energy: its HU are read as attenuation at this energy when the
  // CT is split into water and bone (lftrack/sim/material_decomposition.hpp). A 120 kVp CT with a bow-tie
  // filter has an effective energy of about 65-75 keV.
  double ct_effective_kev = 70;
};

// Scatter-kernel superposition (sim::ScatterModel).
struct ScatterSpec {
  double spr_per_cm = 0.05;     // SPR per cm of water-equivalent thickness, without a grid
  double kernel_sigma_mm = 40;  // at the detector
  bool grid = false;
  double grid_primary_transmission = 0.70;
  double grid_scatter_transmission = 0.15;
};

// A flat panel's glare, lag, residual gain, defects and heel (sim::DetectorPattern and the frame
// synthesizer).
struct DetectorEffectsSpec {
  double glare_fraction = 0;  // share of the signal spread by the glare kernel
  double glare_sigma_mm = 3;
  double lag_fraction = 0;              // share of the previous frame's signal in this one
  double gain_smooth_rms = 0;           // relative gain error, smooth over the detector
  double gain_pixel_rms = 0;            // relative gain error, independent per pixel
  double defective_pixel_fraction = 0;  // pixels stuck at a fixed level
  int defective_lines = 0;              // rows or columns with a wrong gain
  double heel_gradient = 0;             // relative intensity change from the detector's top row to its bottom
  std::uint64_t pattern_seed = 1;
};

// The patient on the day is not the planning CT: soft tissue, adjacent vertebrae and breathing
// anatomy displaced around a rigid target box (sim::AnatomyDeformation).
struct AnatomySpec {
  double soft_tissue_mm = 0;
  double soft_tissue_scale_mm = 80;
  double ramp_mm = 40;
  double adjacent_translation_mm = 0;  // each segment: per axis uniform in +-this
  double adjacent_rotation_deg = 0;    // each segment: per axis uniform in +-this
  double disc_mm = 8;
  double breathing_mm = 0;
  Eigen::Vector3d target_size_mm{60, 60, 30};
  std::uint64_t seed = 1;  // the draw a scene's simulated patient takes (studies draw their own)
};

struct XrayPhysicsSpec {
  std::optional<BeamSpec> spectrum;
  std::optional<ScatterSpec> scatter;
  std::optional<DetectorEffectsSpec> detector;
  std::optional<AnatomySpec> anatomy;
  bool ideal() const { return !spectrum && !scatter && !detector && !anatomy; }
};

// "ideal" or "clinical".
Result<XrayPhysicsSpec> physics_preset(const std::string& name);
std::vector<std::string> physics_preset_names();

// The clinical preset's parts (what `physics_preset("clinical")` holds): 120 kVp with 2.5 mm Al
// (the clinical preset images at the same kVp as the planning CT, whose effective energy differs
// from the imaging beam's through the filtration); scatter 0.05 per cm, a 40 mm kernel, a 10:1
// grid; the detector values of lftrack/sim/detector_effects.hpp; anatomy 3 mm soft tissue, 1 mm / 1 degree
// adjacent vertebrae, no breathing (a thoracic scene sets breathing_mm).
XrayPhysicsSpec clinical_physics();
BeamSpec clinical_beam();
ScatterSpec clinical_scatter();
DetectorEffectsSpec clinical_detector();
AnatomySpec clinical_anatomy();

// The ranges each part's model is defined on. check_spectrum_spec: kVp in [40, 150] (the
// attenuation tables end at 150 keV), filtration in [0, 20] mm Al, bins in [0.01, 10] keV.
Status check_spectrum_spec(const SpectrumSpec& spec);
Status check_scatter_spec(const ScatterSpec& spec);
Status check_detector_effects(const DetectorEffectsSpec& spec);
Status check_anatomy_spec(const AnatomySpec& spec);
Status check_physics(const XrayPhysicsSpec& spec);

// One line per part that is on, for logs and study reports.
std::string describe(const XrayPhysicsSpec& spec);

}  // namespace lftrack::sim_spec
