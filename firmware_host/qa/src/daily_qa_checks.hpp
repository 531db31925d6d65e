#pragma once
// The daily QA's judges (daily_qa.cpp runs the QA): each run of the loop the QA makes, judged
// against its tolerance, and the words the checks use for shifts.

#include <string>
#include <vector>

#include "daily_qa_runs.hpp"
#include "lftrack/qa/daily_qa.hpp"

namespace lftrack::qa {

double translation_mm(const tracking::Vector6d& v);        // its translation's length
double largest_rotation_deg(const tracking::Vector6d& v);  // its largest rotation component
std::string shift_text(const tracking::Vector6d& v);       // "(+10.0, +0.0, +0.0) mm, (...) deg"

// One shift's run judged: the alignment's registration against the shift, the couch's read-back
// against the move that undoes it, and the last registration against nothing left to correct.
OffsetResult judge_offset(const tracking::Vector6d& shift, const RecordedRun& run, const DailyQaOptions& o);
// The offset test over every shift's result.
QaCheck offset_check(const std::vector<OffsetResult>& offsets, const DailyQaOptions& o);
// The detectors dark in [dark_from, dark_to): the beam on while tracking before the fault (the
// path is live), no HOLD before it, the beam off in every dark cycle, a HOLD within
// `hold_after` lost pairs (the scene's safety.hold_after_failures), and the beam never on again
// without an operator (none is given).
QaCheck beam_check(const RecordedRun& run, int dark_from, int hold_after);
// The real-clock run: every cycle tracked, the control socket's TRACK, no overrun, and exposure
// to acknowledgement p99 within `tolerance_ms`.
QaCheck latency_check(const RecordedRun& run, double tolerance_ms, int cycles);
// A check whose run could not be made (a room's devices that failed it, an interruption):
// failed, with the reason.
QaCheck not_run(const std::string& name, const std::string& tolerance, const std::string& why);

}  // namespace lftrack::qa
