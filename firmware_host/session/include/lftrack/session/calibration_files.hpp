#pragma once
// Files of `lftrack calibrate`: the calibration phantom (YAML, read), the calibrated detectors
// (YAML: a scene's `detectors:` section plus a `calibration:` report, written), and the couch
// calibration (YAML, written by `calibrate couch` and read by scenes through
// `actuator.calibration`).
//
// Phantom file:
//   name: my phantom
//   marker_diameter_mm: 3
//   body_size_mm: [140, 140, 140]     # optional plastic box centred on the origin
//   markers_mm:                       # ball centres in the phantom's frame
//     - [30.0, 0.0, -58.0]
//     - ...

#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/calib/calibration_phantom.hpp"
#include "lftrack/calib/couch_calibration.hpp"
#include "lftrack/calib/two_view_calibration.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::session {

// "builtin" gives calib::builtin_calibration_phantom(); anything else is a phantom file.
Result<calib::CalibrationPhantom> load_calibration_phantom(const std::string& file_or_builtin);

// The calibrated views as a scene's detector section (explicit geometry, room frame; frames,
// bits from `specs`, which must be in the same order), followed by the report.
std::string calibrated_detectors_yaml(const std::vector<DetectorSpec>& specs,
                                      const calib::TwoViewCalibration& calibration,
                                      const std::string& provenance);

// Couch calibration file:
//   couch_calibration:
//     rotation_deg: [rx, ry, rz]   # rotation vector of the couch's axes in the room (room from couch)
//     centre_mm: [x, y, z]         # its rotation centre, room frame
//     ...                          # the solver's report (rms, standard deviations, moves)
Result<CouchMountingSpec> read_couch_calibration(const std::string& file);
// The file for a solved calibration, with the solver's report (rms, standard deviations, number
// of moves) and where it came from.
std::string couch_calibration_yaml(const calib::CouchCalibration& calibration, std::size_t moves,
                                   const std::string& provenance);

// Couch moves file: absolute couch positions in the couch's own terms, from where it starts:
//   moves:
//     - {translation_mm: [10, 0, 0]}
//     - {rotation_deg: [0, 0, 2]}
//     - {translation_mm: [0, 5, 0], rotation_deg: [1, 0, 0]}
Result<std::vector<tracking::Vector6d>> read_couch_moves(const std::string& file);

}  // namespace lftrack::session
