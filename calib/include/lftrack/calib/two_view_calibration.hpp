#pragma once
// The whole phantom calibration of a two-view room (issue 8): markers found in each image,
// each view calibrated in the phantom's frame (view_calibration.hpp), then both expressed in
// the room frame the two views define (room_frame.hpp). The phantom must not move between the
// two images; where it sits does not matter beyond the nominal guess used for matching.

#include <Eigen/Geometry>
#include <array>

#include "lftrack/calib/calibration_phantom.hpp"
#include "lftrack/calib/marker_detection.hpp"
#include "lftrack/calib/room_frame.hpp"
#include "lftrack/calib/view_calibration.hpp"
#include "lftrack/tracking/image.hpp"

namespace lftrack::calib {

struct TwoViewCalibration {
  std::array<ViewCalibration, 2> in_phantom;     // per view, phantom frame, with residuals
  std::array<MarkerScanResult, 2> scans;         // what the marker scan found and rejected
  RoomFrame room;                                // T_room_from_views: phantom -> room
  std::array<tracking::XrayView, 2> views_room;  // the calibrated views, room frame
};

// `nominal_room` are the views as specified, in the room frame; `T_room_from_phantom_nominal`
// where the phantom is believed to sit (identity: at the isocentre, aligned with the room).
// `images` are line-integral images (markers bright), one per view, of the views' sizes.
Result<TwoViewCalibration> calibrate_two_views(const CalibrationPhantom& phantom,
                                               const std::array<tracking::ImageView<const float>, 2>& images,
                                               const std::array<tracking::XrayView, 2>& nominal_room,
                                               const Eigen::Isometry3d& T_room_from_phantom_nominal,
                                               const ViewCalibrationOptions& options = {});

}  // namespace lftrack::calib
