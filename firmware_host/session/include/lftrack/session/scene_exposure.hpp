#pragma once
// The simulated detectors' exposure (sim.exposure), set once when a scene is prepared.
//
// An automatic exposure control (AEC) chooses one technique for the pair, as a room's does for
// its two tubes: the dose at which the ROI of the view that attenuates most reads sim.aec_level
// (default 10 %) of the detector's full scale at the nominal pose. It measures the ideal primary
// (exp(-p) of the exact line integral through the world anatomy, markers included; no noise,
// scatter or spectrum), on every fourth pixel of each ROI window. The open field beyond the
// patient then reads more than full scale and saturates, as it does on a real panel whose AEC
// exposes for the anatomy. Under sim.exposure `fixed` the open field gets sim.photons_per_pixel.
//
// Why: at a fixed 10^4 photons per pixel the oblique view of a real abdomen (a line integral near
// 7.4) kept 6 counts of a 12-bit detector's 4095, about 18 photons: a frame no physicist would
// accept, which the image-quality gate then called blank. At the default level the same view's
// ROI reads about 410 counts, some 1,200 photons per pixel (3 % noise).

#include <string>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::session {

// The open field's level at the detector's reference exposure (sim.photons_per_pixel photons per
// pixel read this fraction of the full scale).
inline constexpr double kReferenceOpenFieldFraction = 0.85;

// The exposure `scene`'s simulated detectors get (its CT, views and ROI windows resolved).
Result<SimExposure> scene_exposure(const PreparedScene& scene);

// One line for people: "AEC: 1.2e+05 photons per pixel in the open field (x12 the detector's
// reference); ROI means 10.0 % (A), 14.2 % (B) of full scale", or the fixed dose.
std::string describe_exposure(const PreparedScene& scene);

}  // namespace lftrack::session
