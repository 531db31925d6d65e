#pragma once
// `lftrack calibrate couch` on the simulated room (issue 8): the calibration phantom lies on the
// virtual couch (mounted as the scene's actuator.mounting says, or ideally); the couch is driven
// through its Actuator interface to each move, allowed to arrive (simulated clock), and the
// phantom's pose is measured from one rendered image per view (calib/phantom_pose.hpp). The
// couch's axes and rotation centre are then solved (calib/couch_calibration.hpp).

#include <Eigen/Geometry>
#include <functional>
#include <vector>

#include "lftrack/calib/calibration_phantom.hpp"
#include "lftrack/calib/couch_calibration.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::sim_devices {

struct CouchCalibrationRunOptions {
  calib::CalibrationPhantom phantom = calib::builtin_calibration_phantom();
  std::vector<tracking::Vector6d> moves;  // absolute couch positions (mm, rad), couch terms; empty: default
  double photons_per_pixel = 1e6;
  std::uint64_t seed = 1;
  std::function<void(int done, int total)> progress;  // optional
};

struct CouchCalibrationRun {
  calib::CouchCalibration calibration;
  std::vector<calib::CouchObservation> observations;
  Eigen::Isometry3d true_T_room_from_couch = Eigen::Isometry3d::Identity();  // the simulated mounting
  double worst_fre_mm = 0;                             // the worst phantom-pose fit over all moves
  double rotation_error_deg = 0, centre_error_mm = 0;  // recovered against the simulated mounting
};

// Twelve moves: +-10 mm along each couch axis, +-2 degrees about each (issue 8's "known moves").
std::vector<tracking::Vector6d> default_couch_moves();

Result<CouchCalibrationRun> run_simulated_couch_calibration(const session::PreparedScene& scene,
                                                            const CouchCalibrationRunOptions& options);

}  // namespace lftrack::sim_devices
