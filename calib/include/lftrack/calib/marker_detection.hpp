#pragma once
// Finding a metal fiducial's projection in a preprocessed frame (line integrals, where metal is
// bright): the pixel of greatest disc-minus-ring contrast within a search radius of the expected
// projection, then the background-subtracted intensity centroid around it (sub-pixel).

#include <Eigen/Core>

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
