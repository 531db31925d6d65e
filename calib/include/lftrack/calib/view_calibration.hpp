#pragma once
// X-ray view geometry from one image of a calibration phantom (issue 8; PAPERS.md, paper 2's
// "camera calibration from a phantom").
//
// Pipeline, all in the phantom's frame:
//   1. correspondence without manual picking: project the phantom with the nominal view, find the
//      image shift most marker pairs agree on (a vote over every model/detection pair), then pair
//      mutual nearest neighbours, refusing ambiguous pairs and ambiguous shifts;
//   2. a direct linear transform (normalised DLT, Hartley) on the pairs, decomposed (RQ) into a
//      source, detector axes, principal point and focal length; re-pairing with it;
//   3. Ceres refinement of the full view (source 3, detector orientation 3, principal point 2,
//      focal length 1) by reprojection error with a Huber loss; pairs beyond `outlier_px` dropped
//      and the fit repeated; standard deviations from the solver's covariance, scaled by the
//      residuals' own variance.
// The detector's distance and its pixel pitch enter the image only as their ratio (the focal
// length in pixels). By default the pitch is the nominal view's and the distance is solved;
// with `fit_pitch` the source-to-detector distance is held at the nominal value and the pitch
// is solved instead.

#include <Eigen/Core>
#include <vector>

#include "lftrack/calib/calibration_phantom.hpp"
#include "lftrack/calib/marker_detection.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::calib {

struct ViewCalibrationOptions {
  bool fit_pitch = false;
  double match_gate_px = 25;  // how far a detection may lie from its shifted nominal projection
  int min_markers = 8;        // fewer matched markers than this is refused
  double huber_px = 1.0;      // robust loss scale
  double outlier_px = 2.0;    // matches whose residual exceeds this (or 6x the median) are dropped
  // Markers whose nominal projections lie closer than this to each other overlap in the image
  // and are not used.
  double min_separation_px = 12;
};

struct MarkerResidual {
  int marker = -1;                                        // index into the phantom's markers
  Eigen::Vector2d detected_px = Eigen::Vector2d::Zero();  // (col, row)
  Eigen::Vector2d residual_px = Eigen::Vector2d::Zero();  // predicted - detected
};

struct ViewCalibration {
  tracking::XrayView view;  // phantom frame
  std::vector<MarkerResidual> residuals;
  double rms_px = 0;
  int markers_matched = 0;
  int markers_projected = 0;  // markers whose nominal projection fell on the detector, unoverlapped
  int detections = 0;
  // 1-sigma standard deviations from the covariance of the final fit.
  Eigen::Vector3d source_sd_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d pixel00_sd_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d orientation_sd_deg = Eigen::Vector3d::Zero();  // about the phantom's axes
  Eigen::Vector2d principal_point_px = Eigen::Vector2d::Zero();  // (col, row) of the foot of the source
  Eigen::Vector2d principal_point_sd_px = Eigen::Vector2d::Zero();
  double source_to_detector_mm = 0, source_to_detector_sd_mm = 0;
  double pitch_col_mm = 0, pitch_sd_mm = 0;  // pitch_sd_mm is 0 unless fit_pitch
};

// `nominal_in_phantom` is the view as specified (pitch, rows, cols, name) and roughly where it
// is, expressed in the phantom's frame. Fails with a message for too few markers, coplanar
// markers, an ambiguous correspondence, a mirrored image, or a fit that does not converge.
Result<ViewCalibration> calibrate_view(const CalibrationPhantom& phantom,
                                       const std::vector<MarkerDetection>& detections,
                                       const tracking::XrayView& nominal_in_phantom,
                                       const ViewCalibrationOptions& options = {});

// Normalised DLT: the 3x4 projection matrix with w (col, row, 1) = P (x, y, z, 1), from >= 6
// non-coplanar point/pixel pairs.
Result<tracking::Matrix34d> projection_from_dlt(const std::vector<Eigen::Vector3d>& points_mm,
                                                const std::vector<Eigen::Vector2d>& pixels);
// The view with projection P (up to scale), taking pitch (col), pitch ratio, rows, cols and name
// from `spec`; the source-to-detector distance follows from the focal length and the pitch.
Result<tracking::XrayView> view_from_projection(const tracking::Matrix34d& projection,
                                                const tracking::XrayView& spec);

}  // namespace lftrack::calib
