#pragma once
// Dark and flood frames of a simulated flat panel (issue 59): what a physicist acquires for the
// detector's calibration (`lftrack calibrate detector`) and for its daily image-quality check
// (calib/detector_qa.hpp), so that the simulated room's QA runs the same check a real room does.
//
//   dark(p)   = dark level + read noise (Gaussian)                                   (counts)
//   flood(p)  = dark(p) + Poisson(photons x heel(row) x gain(p)) x counts per photon
// where counts per photon = open_field_fraction x full scale / photons (the frame synthesizer's
// conversion: synthetic_frames.hpp), and gain, heel and stuck pixels are the detector's fixed
// pattern (detector_effects.hpp; none without effects). A stuck pixel reads its fixed level of
// the open field in every frame, dark or flood. Values are quantised to the bit depth and
// clipped at its full scale.
//
// A model for the QA alone. Here the fixed pattern is the raw panel's, which a calibration of
// these frames removes; in the loop's simulated frames the same pattern is what is left after a
// flat field (detector_effects.hpp), and those frames carry no dark level and are never corrected
// with a calibration made from these. The dark level and read noise exist so that a calibration
// can be made and judged (a noiseless dark frame is a frozen detector's, which calibrate_detector
// refuses).

#include <cstdint>
#include <optional>
#include <vector>

#include "lftrack/sim/detector_effects.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

struct PanelSpec {
  int rows = 0, cols = 0;                      // 1 .. 16384
  int bits = 12;                               // 8 .. 16
  double photons_per_pixel = 10000;            // the open field's quanta per pixel and frame, (0, 1e9]
  double open_field_fraction = 0.85;           // the open field's counts / full scale, (0, 1]
  double dark_fraction = 0.01;                 // the dark level / full scale, [0, 0.5]
  double read_noise_counts = 2;                // (0, 1000]
  std::optional<sim_spec::DetectorEffectsSpec> effects;  // the fixed pattern (effects_of_detector)
};

Status check_panel_spec(const PanelSpec& spec);

// `count` frames (1 .. 1000), dark or flood. Same spec and seed, same frames.
Result<std::vector<tracking::Image<std::uint16_t>>> simulate_panel_frames(const PanelSpec& spec, bool flood,
                                                                          int count, std::uint64_t seed);

}  // namespace lftrack::sim
