#include "lftrack/calib/two_view_calibration.hpp"

#include <algorithm>

namespace lftrack::calib {

Result<TwoViewCalibration> calibrate_two_views(const CalibrationPhantom& phantom,
                                               const std::array<tracking::ImageView<const float>, 2>& images,
                                               const std::array<tracking::XrayView, 2>& nominal_room,
                                               const Eigen::Isometry3d& T_room_from_phantom_nominal,
                                               const ViewCalibrationOptions& options) {
  LFTRACK_RETURN_IF_ERROR(phantom.validate());
  TwoViewCalibration out;
  const Eigen::Isometry3d T_phantom_from_room = T_room_from_phantom_nominal.inverse();
  for (int k = 0; k < 2; ++k) {
    const tracking::XrayView& nominal = nominal_room[std::size_t(k)];
    LFTRACK_RETURN_IF_ERROR(nominal.validate());
    const auto& image = images[std::size_t(k)];
    if (image.rows != nominal.rows || image.cols != nominal.cols) {
      return invalid_argument("view '" + nominal.name + "': image is " + std::to_string(image.rows) + " x " +
                              std::to_string(image.cols) + " pixels, the detector " +
                              std::to_string(nominal.rows) + " x " + std::to_string(nominal.cols));
    }
    MarkerScan scan;
    scan.marker_radius_px =
        projected_ball_radius_px(phantom, nominal, T_room_from_phantom_nominal.translation());
    auto found = scan_markers(image, scan);
    if (!found.ok()) return found.status().with_context("view '" + nominal.name + "'");
    out.scans[std::size_t(k)] = *found;
    // Balls whose projections come closer than 3.5 radii disturb each other's background ring.
    ViewCalibrationOptions view_options = options;
    view_options.min_separation_px = std::max(options.min_separation_px, 3.5 * scan.marker_radius_px);
    auto calibrated =
        calibrate_view(phantom, found->markers, nominal.transformed(T_phantom_from_room), view_options);
    if (!calibrated.ok()) return calibrated.status();
    out.in_phantom[std::size_t(k)] = *calibrated;
  }
  auto room = room_frame_from_views(out.in_phantom[0].view, out.in_phantom[1].view);
  if (!room.ok()) return room.status();
  out.room = *room;
  for (int k = 0; k < 2; ++k) {
    out.views_room[std::size_t(k)] =
        out.in_phantom[std::size_t(k)].view.transformed(out.room.T_room_from_views);
  }
  return out;
}

}  // namespace lftrack::calib
