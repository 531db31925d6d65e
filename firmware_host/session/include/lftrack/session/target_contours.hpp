#pragma once
// A target from a structure set (issue 53): its contours checked, its box, and its voxels on the
// CT's grid. Contours are closed planar polygons in the CT frame (patient LPS, mm), as DICOM's ROI
// Contour Module gives them (CLOSED_PLANAR); nothing here reads a file.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::session {

struct TargetPolygon {
  std::vector<Eigen::Vector3d> points_ct_mm;  // in order, closed (the last joins the first)
};

struct TargetBox {
  Eigen::Vector3d min_ct_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d max_ct_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d centre_ct_mm() const { return 0.5 * (min_ct_mm + max_ct_mm); }
  Eigen::Vector3d size_mm() const { return max_ct_mm - min_ct_mm; }
};

// Each polygon: at least 3 distinct points, finite, on one plane (within kPlanarToleranceMm), of
// non-zero area, and simple (no two edges cross: a self-crossing contour has no inside). `name`
// names the target in the error, with the contour's index.
inline constexpr double kPlanarToleranceMm = 0.1;
Status check_target_polygons(const std::vector<TargetPolygon>& polygons, const std::string& name);

// The box of every point (polygons checked and non-empty).
TargetBox target_box(const std::vector<TargetPolygon>& polygons);

// The target on the CT's grid: 1 where a voxel's centre lies inside the target, else 0 (i
// fastest, as the volume). A voxel is inside when, on the contours of its slice (those whose plane
// passes within half a slice of its centre, along the grid's k axis), it is inside an odd number of
// polygons (holes are polygons inside polygons). Polygons not parallel to the grid's slices are
// refused: a CT's structure set is contoured on its axial slices.
// Refused too: a contour repeated on its slice (two equal polygons cancel each other).
struct TargetMask {
  tracking::VolumeGeometry geometry;
  std::vector<std::uint8_t> inside;
  std::int64_t voxels_inside = 0;
  // The index box of the voxels inside (lo > hi on an axis when none is).
  Eigen::Vector3i lo_index = Eigen::Vector3i::Constant(1 << 30);
  Eigen::Vector3i hi_index = Eigen::Vector3i::Constant(-1);
  int contours_beyond_scan = 0;  // contours whose plane lies beyond the first or last slice
  double most_off_slice_mm = 0;  // the farthest a contour's plane lies from its slice's centre
  double volume_cc() const;
};
Result<TargetMask> rasterise_target(const std::vector<TargetPolygon>& polygons,
                                    const tracking::VolumeGeometry& grid, const std::string& name);

}  // namespace lftrack::session
