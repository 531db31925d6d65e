#pragma once
// The image-quality gate: is a raw detector frame fit to register at all? One pass over the
// region of interest, before preprocessing. A frame that fails is not registered; the cycle
// is skipped with the reason (safety_gate.hpp, "image quality"), never turned into a pose.
//
//   saturated   too many pixels at the detector's saturation (over-exposed, no contrast)
//   dead        too many pixels reading 0 (a dead or disconnected panel region)
//   blank       the signal above the dark level under 1 % of the detector's full scale: a ROI a
//               person sees as black (no exposure, a shutter closed, or a dose far too low for
//               the anatomy: at 12 bits under 41 levels)
//   uniform     almost no spread (no anatomy in the beam, a frozen or test-pattern frame)

#include <cstdint>

#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/image.hpp"

namespace lftrack::tracking {

struct FrameQualityLimits {
  double max_saturated_fraction = 0.25;
  double max_dead_fraction = 0.05;
  // The ROI's mean signal (raw counts less the dark level) as a fraction of full scale (the
  // saturation level). Not of the open field: thick anatomy is dark however well exposed (a real
  // abdomen's oblique view transmits under 0.1 % of the open field), and an automatic exposure
  // control raises the dose until the anatomy reads well inside the detector's range, letting the
  // open field saturate. What makes a frame unusable is a ROI near the bottom of that range.
  double min_mean_of_full_scale = 0.01;
  double min_relative_spread = 0.03;     // standard deviation / mean (photon noise alone is ~1 %)
};

enum class FrameQualityIssue : std::uint8_t { kOk, kSaturated, kDeadPixels, kBlank, kUniform };
const char* to_string(FrameQualityIssue issue);

struct FrameQualityStats {
  // mean_counts and relative_spread are of the signal: raw counts less the dark level.
  double saturated_fraction = 0, dead_fraction = 0, mean_counts = 0, relative_spread = 0;
};

// Over `window` of `raw` (clipped to the frame); allocates nothing. An empty window is kBlank.
FrameQualityIssue assess_frame_quality(const ImageView<const std::uint16_t>& raw, const PixelWindow& window,
                                       const DetectorCorrection& detector, const FrameQualityLimits& limits,
                                       FrameQualityStats* stats = nullptr);

}  // namespace lftrack::tracking
