#pragma once
// A calibration phantom: steel balls at known positions in the phantom's own frame (mm), inside
// an optional plastic body. Read from YAML by the host (`lftrack calibrate views --phantom`);
// the simulator renders it (sim/phantom_images.hpp).

#include <Eigen/Core>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::calib {

struct CalibrationPhantom {
  std::string name;
  std::vector<Eigen::Vector3d> markers_mm;  // ball centres, phantom frame
  double marker_diameter_mm = 2.0;          // steel balls
  Eigen::Vector3d body_size_mm{0, 0, 0};    // plastic box centred on the phantom origin; 0: none
  double marker_mu_per_mm = 0.35;           // steel at ~70 keV effective
  // The body: a rigid foam block in a thin acrylic skin (about 0.004 / mm on average); a solid
  // PMMA block (0.022 / mm) would let through a tenth of the photons.
  double body_mu_per_mm = 0.004;

  // At least 6 finite markers, no two closer than 1.5 diameters, positive diameter, body size
  // >= 0 and (if given) containing every marker.
  Status validate() const;
};

// The phantom lftrack ships for tests and `calibrate views --sim`: 48 steel balls of 3 mm on
// six interleaved helices in a 140 mm foam cube, irregular enough that no shift or rotation of
// a projection looks like another one.
CalibrationPhantom builtin_calibration_phantom();

// The radius (pixels, at least 1) of a ball's projection in `view` when the ball lies at
// `where_mm` (the view's frame): what the marker scan looks for.
double projected_ball_radius_px(const CalibrationPhantom& phantom, const tracking::XrayView& view,
                                const Eigen::Vector3d& where_mm);

}  // namespace lftrack::calib
