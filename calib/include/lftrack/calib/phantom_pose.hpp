#pragma once
// Where a marker phantom is in the room, from one image per calibrated view: each ball found
// near where the guess projects it, triangulated from the two views (triangulation.hpp), and
// the phantom's model fitted to the triangulated balls (least squares, rigid). With 3 mm steel
// balls this is precise to a few micrometres, far better than intensity registration, which
// is why the couch calibration uses it.

#include <Eigen/Geometry>
#include <array>

#include "lftrack/calib/calibration_phantom.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::calib {

struct PhantomPose {
  Eigen::Isometry3d T_room_from_phantom = Eigen::Isometry3d::Identity();
  double fre_rms_mm = 0;      // RMS distance of model to triangulated balls
  double max_ray_gap_mm = 0;  // the worst triangulation's miss distance
  int markers = 0;            // balls seen in both views and used
};

// `views` in the room frame; `images` line integrals (balls bright); `T_guess` within about
// 5 mm and 2 degrees. A coarse pass pairs balls within a wide gate and drops pairings whose two
// rays miss each other by more than 1 mm; a fine pass pairs again around the coarse pose.
// Fails when fewer than 4 balls are found in both views.
Result<PhantomPose> measure_phantom_pose(const CalibrationPhantom& phantom,
                                         const std::array<tracking::XrayView, 2>& views,
                                         const std::array<tracking::ImageView<const float>, 2>& images,
                                         const Eigen::Isometry3d& T_room_from_phantom_guess);

}  // namespace lftrack::calib
