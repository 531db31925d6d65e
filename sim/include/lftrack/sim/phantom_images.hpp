#pragma once
// Synthetic images of a calibration phantom (calib/calibration_phantom.hpp) at a known view
// geometry, for `lftrack calibrate views --sim` and the calibration tests.
//
// A pixel is the detector's average of exp(-line integral) over ss x ss sub-rays (the steel
// balls' chords are exact: 2 sqrt(r^2 - d^2); the plastic body is a box), blurred (Gaussian,
// intensity domain), with Poisson noise of `photons_per_pixel` open-field quanta, returned as
// line integrals p = ln(I0 / I), markers bright.

#include <Eigen/Geometry>
#include <cstdint>

#include "lftrack/calib/calibration_phantom.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::sim {

struct PhantomImageSpec {
  // Open-field quanta per pixel of the calibration exposure: a static phantom allows long
  // integration, e.g. 100 averaged frames of 10^5 quanta. 0: no noise.
  double photons_per_pixel = 1e7;
  double blur_px = 0.5;  // sigma; 0: none
  // Sub-rays per pixel side. Fewer than about 8 leave an aliasing bias of ~0.002 px in the
  // balls' centroids, which alone moves a calibrated source by ~0.3 mm along its beam.
  int supersample = 10;
  std::uint64_t seed = 1;
};

// `view` and the placement `T_view_from_phantom` are in one frame (e.g. the room's).
Result<tracking::Image<float>> render_phantom_image(const calib::CalibrationPhantom& phantom,
                                                    const Eigen::Isometry3d& T_view_from_phantom,
                                                    const tracking::XrayView& view,
                                                    const PhantomImageSpec& spec);

}  // namespace lftrack::sim
