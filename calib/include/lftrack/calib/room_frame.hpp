#pragma once
// The room frame and imaging isocentre from two calibrated views (issue 8), the convention
// lftrack's scenes use (firmware_host/session/src/builtin_scenes.cpp):
//   - origin (isocentre): the midpoint of the shortest segment between the two central rays,
//     each from its source to the centre of its detector (not to the foot of the perpendicular
//     from the source: with a long focal length the detector's tilt is the least well measured
//     part of a view, and the central ray would inherit it);
//   - z: normal to the plane of the two central rays, z = unit(s_B x s_A), where s_A, s_B are
//     the unit vectors from the isocentre towards sources A and B;
//   - y: away from the sources, minus the bisector of s_A and s_B made orthogonal to z (for
//     ceiling sources over a supine patient: towards the floor, LPS posterior);
//   - x = y x z.
// For the built-in room (sources at +-45 degrees in the x-y plane) this gives back the room frame.

#include <Eigen/Geometry>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::calib {

struct RoomFrame {
  Eigen::Isometry3d T_room_from_views = Eigen::Isometry3d::Identity();  // views' frame -> room
  double central_ray_gap_mm = 0;  // how far the two central rays miss each other
  double angle_between_views_deg = 0;
};

// Both views in one frame (e.g. the phantom's). Fails when the central rays are within 10
// degrees of parallel.
Result<RoomFrame> room_frame_from_views(const tracking::XrayView& view_a, const tracking::XrayView& view_b);

}  // namespace lftrack::calib
