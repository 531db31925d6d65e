#pragma once
// The skin entrance dose of the scene's X-ray pairs (issue 58), by a simple stated model rather
// than a Monte Carlo: what a physicist estimates from a tube's output.
//   - tube output at 1 m free in air: kOutputAt100kV (mGy/mAs at 100 kV, a radiographic tube with
//     about 2.5 mm Al; published outputs of such tubes lie within about +-30 % of it), scaled by
//     (kVp / 100)^2;
//   - inverse square to the skin, kSkinBeforeIsocentreMm before the registration origin along each
//     view's central ray (an adult trunk's half-thickness);
//   - a backscatter factor kBackscatter.
// Per view: output(kVp) * mAs * (1000 mm / source-to-skin)^2 * backscatter. A pair's dose adds its
// views' (their fields enter the skin at different places: the sum is the most any one place could
// get only where they overlap; the pair's total is what the summary compares).

#include <string>

#include "lftrack/session/scene.hpp"

namespace lftrack::session {

inline constexpr double kOutputAt100kV = 0.1;          // mGy/mAs at 1 m
inline constexpr double kSkinBeforeIsocentreMm = 150;  // mm
inline constexpr double kBackscatter = 1.35;

// One view's skin entrance dose per exposure (mGy) at `source_to_skin_mm`.
double skin_entrance_dose_mGy(const ImagingTechniqueSpec& technique, double source_to_skin_mm);
// One pair's: every detector's view of the prepared scene, at tracking.imaging.technique.
double imaging_dose_per_pair_mGy(const PreparedScene& scene);
// "120 kV, 2 mAs per view: 0.19 mGy skin entrance per pair (a stated model: docs/scenes.md)".
std::string describe_imaging_dose(const PreparedScene& scene);

}  // namespace lftrack::session
