#pragma once
// The picture a physicist looks at before a new patient's first beam (issue 53), as every set-up
// screen gives: each view's DRR at the nominal pose with the isocentre's cross (green), the ROI's
// box (yellow), the target's outline (red) and, with roi.mask, the edge of what the measures look
// at (cyan) projected on it, above an axial, a coronal and a
// sagittal slice of the CT through the isocentre with the same marks. A mirrored or misplaced
// target shows at once. One PNG; views left to right in the scene's order, then the slices.

#include <filesystem>
#include <vector>

#include "lftrack/session/scene.hpp"
#include "lftrack/session/target_contours.hpp"
#include "lftrack/tracking/image_io.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::session {

struct SetupMarks {
  Eigen::Vector3d isocentre_ct_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d roi_centre_ct_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d roi_size_mm = Eigen::Vector3d::Zero();
  std::vector<TargetPolygon> target_polygons;  // CT frame; none without a structure set
  const TargetMask* target = nullptr;          // on the CT's grid; null without a structure set
};

// The panels, each at most `panel_px` a side: one DRR per view (ray cast, Siddon), then the three
// slices (0.5 mm a pixel, 160 mm across, HU window -400..1200). Colours: see the file comment.
Result<tracking::RgbImage> setup_picture(const PreparedScene& scene, const SetupMarks& marks,
                                         tracking::ThreadPool* pool, int panel_px = 320);

// Counts the pixels of `colour` in `picture` (tests: that a mark was drawn where it should be).
std::int64_t count_colour(const tracking::RgbImage& picture, std::uint8_t red, std::uint8_t green,
                          std::uint8_t blue);

}  // namespace lftrack::session
