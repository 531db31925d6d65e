#pragma once
// Scatter in synthetic frames (issue 21, "Scatter"): scatter-kernel superposition. Each pixel's
// primary signal scatters in proportion to its scatter-to-primary ratio (SPR), which grows
// linearly with the water-equivalent thickness the ray crossed, and the scatter lands spread by a
// broad Gaussian kernel at the detector. Behind a uniform slab of thickness t the measured
// signal is therefore primary x (1 + SPR(t)), the property the tests check.
//
// An anti-scatter grid passes a fraction Tp of the primary and Ts of the scatter. The flat field
// is taken with the grid in place, so signals here are relative to the gridded open field: the
// grid lowers the SPR by Ts / Tp and the photons counted (the dose reaching the detector) by Tp.
//
// Typical values (the clinical preset's): SPR about 0.05 per cm of water for the 10-15 cm
// fields of kV image guidance, e.g. 1.0 behind 20 cm (Siewerdsen and Jaffray, Med. Phys. 28
// (2001) 220, fig. 4: SPR 0.2-1.6 over 10-30 cm and small to large fields); kernel width 40 mm
// at the detector; a 10:1 grid with Tp 0.70 and Ts 0.15 (typical of 8:1-12:1 grids).
//
// Scatter comes only from the rendered window (the collimated field), spread with the mask-aware
// normalised convolution at its edges.

#include <vector>

#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

class ScatterModel {
 public:
  // Sized for `rows` x `cols` images of pixels `pitch_mm` wide. The spec must pass
  // sim_spec::check_scatter_spec.
  ScatterModel(int rows, int cols, double pitch_mm, const sim_spec::ScatterSpec& spec);

  // The SPR measured behind `thickness_cm` of water-equivalent material, after the grid.
  double measured_spr(double thickness_cm) const;
  // Photons reaching the detector per open-field photon without the grid (Tp, or 1).
  double photon_fraction() const;

  // out = primary + scatter, where primary is the signal relative to the open field (1 = open)
  // and thickness_cm the water-equivalent path of each pixel's ray. No allocation.
  Status add_scatter(const tracking::ImageView<const float>& primary,
                     const tracking::ImageView<const float>& thickness_cm, tracking::ImageView<float> out);

 private:
  sim_spec::ScatterSpec spec_;
  int rows_, cols_, factor_;  // the scatter is spread on a grid `factor_` times coarser
  int coarse_rows_, coarse_cols_;
  tracking::Image<float> coarse_amplitude_, coarse_weight_, coarse_scatter_;
  tracking::Image<unsigned char> coarse_valid_;
  tracking::GaussianBlur blur_;
};

}  // namespace lftrack::sim
