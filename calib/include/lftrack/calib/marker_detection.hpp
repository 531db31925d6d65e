#pragma once
// Finding a metal fiducial's projection in a preprocessed frame (line integrals, where metal is
// bright): on the 3 x 3 median of the search area (stuck pixels and one-pixel bad lines gone),
// the pixel of greatest disc-minus-ring contrast within a search radius of the expected
// projection whose disc is also brighter than every sector of its ring (a blob, not a bone edge
// or ridge), then the background-subtracted intensity centroid around it (sub-pixel).

#include <Eigen/Core>
#include <vector>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::calib {

struct MarkerSearch {
  Eigen::Vector2d expected_px = Eigen::Vector2d::Zero();  // (col, row) in the image
  double search_radius_px = 40;
  double marker_radius_px = 3;  // of the marker's projection
  // Least disc-minus-ring contrast (line-integral units) that counts as a marker.
  double min_contrast = 0.05;
};

struct MarkerDetection {
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();  // (col, row), sub-pixel
  double contrast = 0;
};

// Fails with a message when no usable pixel lies in the search area or the best contrast is
// below min_contrast. `valid` may be empty.
Result<MarkerDetection> find_marker(const tracking::ImageView<const float>& image,
                                    const tracking::ImageView<const unsigned char>& valid,
                                    const MarkerSearch& search);

}  // namespace lftrack::calib

namespace lftrack::calib {

struct MarkerScan {
  double marker_radius_px = 3;  // expected radius of a marker's projection
  // Least contrast over the local background (line-integral units); the threshold is the larger
  // of this and `noise_sigmas` times the image's robust noise level.
  double min_contrast = 0.05;
  double noise_sigmas = 6;
  int border_px = 4;  // blobs closer than this to the image edge are dropped (cut off)
};

struct MarkerScanResult {
  std::vector<MarkerDetection> markers;  // sub-pixel, in row-major order of their first pixel
  int rejected_merged = 0;               // blobs too large or elongated: overlapping projections
  int rejected_small = 0;                // blobs too small for a marker (noise, dust)
  int rejected_border = 0;               // cut off by the image edge
};

// Every marker-like blob in a whole image (line integrals, markers bright): threshold the image
// minus its local mean, group pixels into blobs, drop those of the wrong size or shape, and
// locate each survivor to sub-pixel precision with find_marker(). Never fails on an image with
// no markers (returns none); fails on an empty image or a bad option.
Result<MarkerScanResult> scan_markers(const tracking::ImageView<const float>& image, const MarkerScan& scan);

}  // namespace lftrack::calib
