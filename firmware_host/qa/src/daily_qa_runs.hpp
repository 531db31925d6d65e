#pragma once
// The loop runs the daily QA makes (daily_qa.cpp judges them): a session of the scene's room with
// every cycle's record kept.

#include <optional>
#include <string>
#include <vector>

#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/loop_summary.hpp"
#include "lftrack/qa/daily_qa.hpp"
#include "lftrack/session/loop_session.hpp"

namespace lftrack::qa {

struct RecordedRun {
  loop::LoopSummary summary;
  std::vector<loop::JournalRecord> records;  // every cycle, in order
  std::string control_reply;                 // the latency run: the control socket's answer
  // A room: where the couch stood (its travel) before it made the shift, to send it back there
  // when the shift fails.
  std::optional<tracking::Vector6d> couch_before;
};

// Whether the operator has interrupted the QA (options.interrupted set).
inline bool interrupted(const DailyQaOptions& options) {
  return options.interrupted != nullptr && options.interrupted->load();
}
// The record of the cycle that ended the alignment with its set-up move (ALIGN to TRACK); end()
// if the run never aligned.
std::vector<loop::JournalRecord>::const_iterator alignment_record(
    const std::vector<loop::JournalRecord>& records);

// A report of `kind` ("daily", "e2e") for `scene`, started now: the scene, the room's fingerprint,
// the times.
DailyQaReport new_report(const session::PreparedScene& scene, const std::string& kind);

// The detector options judged against `scene` (detector_checks.cpp): tolerances in range, frames
// for every detector or none.
Status check_detector_qa_options(const session::PreparedScene& scene, const DetectorQaOptions& options);
// What the detector checks cannot judge in `scene`: simulated detectors without a calibration file
// are judged against their panel's calibration made as the QA starts (no history, no drift).
std::optional<std::string> simulated_detector_note(const session::PreparedScene& scene,
                                                   const DetectorQaOptions& options);

// Whether `scene` is a room whose actuator is a device (modbus, can): its couch makes the shifts
// and every run is on the real clock with the scene's devices (room_runs.hpp). Otherwise a
// simulated room: the simulated patient's set-up error is the shift, and the runs that can be are
// on the simulated clock.
bool is_room(const session::PreparedScene& scene);

// `scene` with the phantom `shift` off (no drift or breathing), `cycles` on the simulated
// clock; in a room, the couch moved by `shift` first (an error when it does not get there) and
// the real clock.
Result<RecordedRun> run_offset(const session::PreparedScene& scene, const tracking::Vector6d& shift,
                               int cycles, const DailyQaOptions& options, tracking::ThreadPool* pool);
// `scene` standing still, `cycles` on the simulated clock, exposures [dark_from, dark_to) lost.
Result<RecordedRun> run_dark_detectors(const session::PreparedScene& scene, int cycles, int dark_from,
                                       int dark_to, const DailyQaOptions& options,
                                       tracking::ThreadPool* pool);
// `scene` as it is (its own set-up error and motion), `cycles` on the simulated clock.
Result<RecordedRun> run_tracking(const session::PreparedScene& scene, int cycles,
                                 const DailyQaOptions& options, tracking::ThreadPool* pool);
// `scene` standing still on the real clock with a control socket, asked `status` once it tracks.
Result<RecordedRun> run_real_clock(const session::PreparedScene& scene, int cycles,
                                   const DailyQaOptions& options, tracking::ThreadPool* pool);

}  // namespace lftrack::qa
