#include "lftrack/calib/calibration_phantom.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace lftrack::calib {

Status CalibrationPhantom::validate() const {
  const std::string who = "phantom '" + name + "': ";
  if (markers_mm.size() < 6) {
    return invalid_argument(who + "needs at least 6 markers, has " + std::to_string(markers_mm.size()));
  }
  if (!(marker_diameter_mm > 0) || !std::isfinite(marker_diameter_mm)) {
    return invalid_argument(who + "marker diameter must be positive");
  }
  if (!body_size_mm.allFinite() || (body_size_mm.array() < 0).any()) {
    return invalid_argument(who + "body size must be finite and >= 0");
  }
  if (!(marker_mu_per_mm > 0) || !(body_mu_per_mm >= 0)) {
    return invalid_argument(who + "attenuation coefficients must be positive");
  }
  const bool has_body = (body_size_mm.array() > 0).all();
  for (std::size_t i = 0; i < markers_mm.size(); ++i) {
    if (!markers_mm[i].allFinite())
      return invalid_argument(who + "marker " + std::to_string(i) + " is not finite");
    if (has_body && ((markers_mm[i].cwiseAbs() * 2).array() > body_size_mm.array()).any()) {
      return invalid_argument(who + "marker " + std::to_string(i) + " lies outside the body");
    }
    for (std::size_t j = 0; j < i; ++j) {
      if ((markers_mm[i] - markers_mm[j]).norm() < 1.5 * marker_diameter_mm) {
        std::ostringstream m;
        m << who << "markers " << j << " and " << i << " are closer than 1.5 diameters ("
          << (markers_mm[i] - markers_mm[j]).norm() << " mm)";
        return invalid_argument(m.str());
      }
    }
  }
  return {};
}

double projected_ball_radius_px(const CalibrationPhantom& phantom, const tracking::XrayView& view,
                                const Eigen::Vector3d& where_mm) {
  const double depth = std::max(view.detector_normal().dot(view.source_mm - where_mm), 1.0);
  const double magnification = view.source_to_detector_mm() / depth;
  return std::max(
      1.0, 0.5 * phantom.marker_diameter_mm * magnification / std::min(view.pitch_col_mm, view.pitch_row_mm));
}

CalibrationPhantom builtin_calibration_phantom() {
  CalibrationPhantom p;
  p.name = "lftrack helix cube";
  p.marker_diameter_mm = 3.0;
  p.body_size_mm = {140, 140, 140};
  // Six helices about the z axis, 8 balls each, radii 30..60 mm, with pitches and phases that
  // differ, so that the pattern has no symmetry a shift or rotation could mistake. The balls
  // fill the field a 1.4x magnified 205 mm detector sees at the isocentre: the source's distance
  // is measured by how magnification changes with depth, so depth and width are what count.
  for (int h = 0; h < 6; ++h) {
    const double radius = 30 + 6 * h;
    const double phase = 0.7 * h + 0.3 * h * h;
    const double turn = (h % 2 == 0 ? 1.0 : -1.0) * (0.55 + 0.07 * h);
    for (int k = 0; k < 8; ++k) {
      const double angle = phase + turn * k + 0.05 * k * k;
      const double z = -58 + 15.5 * k + 2.3 * h;
      p.markers_mm.emplace_back(radius * std::cos(angle), radius * std::sin(angle), z);
    }
  }
  return p;
}

}  // namespace lftrack::calib
