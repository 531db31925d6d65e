#pragma once
// The image-quality gate: is a raw detector frame fit to register at all? One pass over the
// region of interest, before preprocessing. A frame that fails is not registered; the cycle
// is skipped with the reason (safety_gate.hpp, "image quality"), never turned into a pose.
//
//   saturated   too many pixels at the detector's saturation (over-exposed, no contrast)
//   dead        too many pixels reading 0 (a dead or disconnected panel region)
//   blank       mean far below the open field (no exposure: tube off, shutter closed)
//   uniform     almost no spread (no anatomy in the beam, a frozen or test-pattern frame)

#include <cstdint>

#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/image.hpp"

namespace lftrack::tracking {

struct FrameQualityLimits {
  double max_saturated_fraction = 0.25;
  double max_dead_fraction = 0.05;
  // Mean raw counts / I0. Thick anatomy is dark: the built-in phantom's spine ROI averages about
  // 1 % of the open field (a mean line integral near 4.6), so blank means below 0.2 %.
  double min_mean_of_open_field = 0.002;
  double min_relative_spread = 0.03;     // standard deviation / mean (photon noise alone is ~1 %)
};

enum class FrameQualityIssue : std::uint8_t { kOk, kSaturated, kDeadPixels, kBlank, kUniform };
const char* to_string(FrameQualityIssue issue);

struct FrameQualityStats {
  double saturated_fraction = 0, dead_fraction = 0, mean_counts = 0, relative_spread = 0;
};

// Over `window` of `raw` (clipped to the frame); allocates nothing. An empty window is kBlank.
FrameQualityIssue assess_frame_quality(const ImageView<const std::uint16_t>& raw, const PixelWindow& window,
                                       const DetectorCorrection& detector, const FrameQualityLimits& limits,
                                       FrameQualityStats* stats = nullptr);

}  // namespace lftrack::tracking
