#pragma once
// Target registration error (PAPERS.md, papers 1 and 2): the distance between where a pose and
// the gold pose put each voxel centre of a box around the target, as mean and max.

#include <Eigen/Core>

#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::tracking {

struct TreBox {
  Eigen::Vector3d centre_ct_mm = Eigen::Vector3d::Zero();
  double edge_mm = 40;  // a cube of this edge, axis-aligned with the CT grid
};

struct Tre {
  double mean_mm = 0;
  double max_mm = 0;
  int points = 0;  // voxel centres in the box
};

// Over every voxel centre of `grid` inside the box (at least the box centre when the box holds
// none). Poses map the CT frame to the room frame; distances are in the room frame.
Tre target_registration_error(const Pose& T_room_from_ct, const Pose& gold_T_room_from_ct,
                              const VolumeGeometry& grid, const TreBox& box);

}  // namespace lftrack::tracking
