#pragma once
// roi.mask (issue 53): where in each view's ROI window the similarity measures look. The target's
// contours (an RT Structure Set of the scene's DICOM CT, checked as `scene new` checks them) are
// filled on the CT's grid, each voxel inside projected at the nominal pose as the box its corners
// span, and the projection grown by the margin (mm at the isocentre, scaled to the detector). The
// mask is fixed on the detector: the target moves within it by the envelope, which the margin
// should exceed.

#include <cstdint>
#include <vector>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::session {

// One mask per detector, each its ROI window's size (1: look). Refused: no roi.mask in the
// scene, a CT that is not a DICOM series, a structure set or target that does not belong to it
// (target_from_structure_set), a mask of fewer than kMinRoiMaskPixels in a view's window (a 4 x 4
// binned level keeps 16 blocks of it at best; the Registration refuses any level of a plan that
// keeps fewer than a measure needs).
inline constexpr std::int64_t kMinRoiMaskPixels = 256;
Result<std::vector<tracking::Image<unsigned char>>> project_roi_mask(const PreparedScene& scene);

}  // namespace lftrack::session
