#pragma once
// The daily QA of a treatment room (issue 59; AAPM TG-135 for robotic radiosurgery, MPPG 9.a): run
// each morning on the room's phantom before the first patient, every check pass or fail against
// its stated tolerance.
//
//  offset      TG-135's daily offset test. For each known shift (up to 10 mm and 1 degree by
//              default) the phantom starts displaced by it, and the loop runs as in treatment on the
//              simulated clock: its alignment must find the shift within the tolerance (0.5 mm and
//              0.2 degree by default: MPPG 9.a's 1 mm for SRS with margin), the couch's read-back
//              must then show it moved by the shift, and the last registration must find the
//              phantom back in place.
//  beam        the beam-permit path: the detectors go dark for some cycles in TRACK; the loop must
//              HOLD, withhold the beam in every HOLD cycle, and never permit it again without an
//              operator (none is given).
//  detector    one per detector: its image quality against its calibration (detector_checks below).
//  latency     on the real clock: the loop runs its period with the room's devices, the control
//              socket answers `status` with the loop's state, no cycle overruns, and the exposure
//              to the actuator's acknowledgement stays within the tolerance (the period by
//              default) at p99.
//
// Runs in a simulated room (the scene's detectors `frames: sim`, a virtual actuator), where the
// shifts are the simulated patient's set-up error and the runs are on the simulated clock, or in
// a room whose actuator is a device (modbus, can), where the room's couch makes each shift and
// every run is on the real clock with the scene's devices (src/room_runs.hpp). A scene with
// device detectors and no device actuator is refused: nothing would make the shifts.

#include <Eigen/Core>
#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "lftrack/calib/detector_qa.hpp"
#include "lftrack/qa/daily_qa_report.hpp"
#include "lftrack/session/loop_session.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::qa {

inline constexpr double kStandardToleranceMm = 0.5;
inline constexpr double kStandardToleranceDeg = 0.2;
inline constexpr int kStandardLatencyCycles = 50;
inline constexpr double kStandardShiftMm = 10;  // TG-135's daily offset shifts
inline constexpr double kStandardShiftDeg = 1;

// Today's frames of one detector as a physicist acquires them for its check: dark (no beam) and
// flood (open beam, nothing in it), each of the detector's full size.
struct DetectorFrames {
  std::vector<tracking::Image<std::uint16_t>> dark, flood;
  std::string unreadable;  // why the frames could not be read (the detector's check fails with it)
};

// The detectors' image quality against their calibration (calib/detector_qa.hpp: dark drift,
// noise, flat-field uniformity, new defects), one check per detector, named "detector NAME".
//   baseline  the detector's calibration file (detectors[i].calibration; one made for another
//             detector fails the check, as `lftrack run` refuses it); for a simulated detector
//             without one, the calibration of its simulated panel (sim/panel_frames.hpp) made
//             from its commissioning frames (16 dark, 16 flood, seed 1) as the QA starts.
//   today     `frames[i]` where given; else a simulated detector's panel gives 8 dark and 8
//             flood frames (seed 2). A detector with neither (a device, no frames given) fails
//             its check, saying how to give them.
// Floods are taken at half the detector's full scale (the scene's conversion of photons to
// counts), as a calibration is: an open field that saturates calibrates nothing.
struct DetectorQaOptions {
  calib::DetectorQaTolerances tolerances;
  std::vector<DetectorFrames> frames;  // empty, or one per detector in the scene's order
  // Fault injection (tests): changes detector `index`'s frames of today before they are judged.
  std::function<void(int index, DetectorFrames* today)> fault;
};

struct DailyQaOptions {
  double tolerance_mm = kStandardToleranceMm;    // offset test: registration and couch, per shift (3D)
  double tolerance_deg = kStandardToleranceDeg;  // offset test: largest rotation component
  // The known shifts (mm, rad, about the registration origin); empty: default_offset_shifts().
  std::vector<tracking::Vector6d> shifts;
  int offset_cycles = 20;  // per shift: the alignment, then the couch's move (simulated clock)
  int beam_cycles = 40;    // beam-permit run: the detectors dark from cycle 15 to 25
  // Real-clock run for the latency chain and the control socket; 0: not run (the check is then
  // reported as not run and the QA does not pass).
  int latency_cycles = kStandardLatencyCycles;
  double latency_tolerance_ms = 0;        // p99 exposure to acknowledgement; 0: the scene's period
  std::filesystem::path light_field_dir;  // empty: the scene's default folder
  std::filesystem::path work_dir;         // the control socket; empty: a folder in /tmp
  DetectorQaOptions detectors;
  // Fault injection (tests): wraps the devices of every run, as the chaos soak does.
  session::SessionHooks hooks;
  // Called with a line per step done (a progress display); may be empty.
  std::function<void(const std::string&)> progress;
  // Set (by the operator's Ctrl-C; null: never) to end the QA early: the run in progress stops
  // before its next cycle, a room's couch is sent back to where it stood before the shift it was
  // making (and waited for), and every check not run is reported failed, "interrupted by the
  // operator". The report is still made: an interrupted morning is a failed one.
  const std::atomic<bool>* interrupted = nullptr;
};

// The reason a check or shift gives when the QA was interrupted.
inline constexpr const char* kInterrupted = "interrupted by the operator";

// The default shifts: 10 mm along each room axis, 1 degree about each, and one of each kind at
// once (5, -5, 5 mm with 0.5, -0.5, 0.5 degree), where the scene's envelope and its safety gate's
// total correction (safety.max_total_mm, _deg) allow them: a shift beyond 90 % of either is scaled
// to 90 % (the verdict refuses results at the envelope's edge, the gate a total a hair over).
std::vector<tracking::Vector6d> default_offset_shifts(const session::Scene& scene);

// Runs the checks on `scene` (prepared, with its light fields built). Fails only when a run
// cannot be made at all (a room with nothing to make the shifts, light fields missing); a check
// that fails is in the report, and so is a shift the room's couch could not make.
Result<DailyQaReport> run_daily_qa(const session::PreparedScene& scene, const DailyQaOptions& options,
                                   tracking::ThreadPool* pool);

// The detector checks alone, on any room (real devices too): a report of kind "detector". It is
// not a daily QA (`lftrack run` does not count it); a real room runs it each morning with its
// detectors' frames until its daily QA can move the room's own couch. Fails only for options out
// of range; a detector that cannot be judged fails its check.
std::vector<QaCheck> detector_checks(const session::PreparedScene& scene, const DetectorQaOptions& options,
                                     const std::function<void(const std::string&)>& progress);
Result<DailyQaReport> run_detector_qa(const session::PreparedScene& scene, const DetectorQaOptions& options,
                                      const std::function<void(const std::string&)>& progress);

// The hidden-target end-to-end test (AAPM TG-135's yearly E2E, MPPG 9.a: within 1.0 mm): the
// room's phantom tracked as in treatment, with the scene's own set-up error and motion, on the
// simulated clock; a marker the registration never sees (a point `marker_offset_room_mm` from
// the registration origin, not in the ROI's image terms) is followed through the simulator's
// truth, and its distance from where the plan puts it, in every cycle the beam is on, must stay
// within the tolerance (p95; mean and max reported).
struct EndToEndOptions {
  int cycles = 300;  // 100 to 100,000
  Eigen::Vector3d marker_offset_room_mm{0, 0, 20};
  double tolerance_mm = 1.0;
  std::filesystem::path light_field_dir;
  session::SessionHooks hooks;
  std::function<void(const std::string&)> progress;
};
Result<DailyQaReport> run_end_to_end_qa(const session::PreparedScene& scene, const EndToEndOptions& options,
                                        tracking::ThreadPool* pool);

}  // namespace lftrack::qa
