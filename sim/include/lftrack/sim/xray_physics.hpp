#pragma once
// The imaging physics a scene asks of its synthetic frames (scene section `sim.physics`; DESIGN.md
// "Simulated imaging physics"; issue 21). Each part is optional; none at all is the `ideal`
// preset: today's frames (mono-energetic DRRs of the planning CT with photon noise, detector
// blur and quantisation). `clinical` switches every part on at typical values, each with its
// source at its definition (xray_spectrum.hpp, scatter_model.hpp, detector_effects.hpp,
// anatomy_deformation.hpp).

#include <optional>
#include <string>
#include <vector>

#include "lftrack/sim/anatomy_deformation.hpp"
#include "lftrack/sim/detector_effects.hpp"
#include "lftrack/sim/scatter_model.hpp"
#include "lftrack/sim/xray_spectrum.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

struct BeamSpec {
  SpectrumSpec spectrum;
  // The planning CT's effective energy: its HU are read as attenuation at this energy when the
  // CT is split into water and bone (material_decomposition.hpp). A 120 kVp CT with a bow-tie
  // filter has an effective energy of about 65-75 keV.
  double ct_effective_kev = 70;
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
// grid; the detector values of detector_effects.hpp; anatomy 3 mm soft tissue, 1 mm / 1 degree
// adjacent vertebrae, no breathing (a thoracic scene sets breathing_mm).
XrayPhysicsSpec clinical_physics();
BeamSpec clinical_beam();
ScatterSpec clinical_scatter();
DetectorEffectsSpec clinical_detector();
AnatomySpec clinical_anatomy();

Status check_physics(const XrayPhysicsSpec& spec);

// One line per part that is on, for logs and study reports.
std::string describe(const XrayPhysicsSpec& spec);

}  // namespace lftrack::sim
