#pragma once
// The start-up checks before the first beam (`lftrack run` runs them and refuses to start on any
// failure, listing every reason; `lftrack run --check` runs only them and prints the
// pre-treatment checklist):
//   - the real-time set-up holds in enforce mode (or the operator waived it with --rt ignore);
//   - the light fields are fresh for this CT and geometry (none is built at treatment time);
//   - each detector opens and identifies itself (V4L2 or GigE format and size; a replayed
//     sequence reads), then is closed again; a GigE camera must answer with the device id the
//     scene's frames.id names, and a served twin (lftrack serve detectors) as its own detector's
//     (served_twin_id), so swapped cables or addresses fail here, naming who answered where;
//   - each device detector has its detector calibration, made for a detector of its name and
//     size (the file's content hash is checked when it loads); `calibration: simulator` only
//     where the detector answered as the simulator's served twin of itself;
//   - the couch or robot opens, answers a read-back (and, for CAN, its heartbeat), and is
//     held and closed again: nothing moves;
//   - the couch calibration, where named, loads; where not, a warning says that corrections
//     assume the couch's axes are the room's.
// Nothing here moves the patient or switches the beam on.

#include <optional>
#include <string>
#include <vector>

#include "lftrack/loop/realtime_setup.hpp"
#include "lftrack/session/loop_session.hpp"
#include "lftrack/session/scene.hpp"

namespace lftrack::session {

enum class CheckResult { kPass, kWarn, kFail };

struct PreflightItem {
  std::string what;  // "detector A (v4l2 /dev/v4l/by-path/...)"
  CheckResult result = CheckResult::kPass;
  std::string detail;  // what was found, or why it fails and what to do
};

struct PreflightReport {
  std::vector<PreflightItem> items;
  // The couch's or robot's read-back at the checks (total travel, mm and rad), where it answered:
  // what a simulated room's checks compare its served couch's room link with.
  std::optional<tracking::Vector6d> actuator_position;
  void add(std::string what, CheckResult result, std::string detail);  // one item, in order
  bool passed() const;                                                 // no kFail
  std::string checklist() const;  // one line per item: [ ok ] / [warn] / [FAIL]
  std::string failures() const;   // every failing item's reason, one per line
};

// `realtime`: the outcome of apply_realtime_setup (its status, and its report when it
// succeeded); `rt_waived`: the operator gave --rt ignore.
PreflightReport run_preflight(const PreparedScene& scene, const LoopSessionOptions& options,
                              const Result<loop::RealtimeReport>& realtime, bool rt_waived);

}  // namespace lftrack::session
