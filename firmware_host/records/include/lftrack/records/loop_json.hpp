#pragma once
// The JSON forms of what a run of the loop reports (loop_summary.hpp, tracking_accuracy.hpp), for
// `sim --json`, `journal export`, the monitor and the tests. Outside the loop, which links no JSON.

#include <nlohmann/json.hpp>

#include "lftrack/loop/loop_summary.hpp"
#include "lftrack/loop/tracking_accuracy.hpp"

namespace lftrack::records {

nlohmann::json to_json(const loop::LoopSummary& summary);

// A pose delta or correction (tx, ty, tz in mm; a rotation vector in radians, as the journal
// keeps it) as every report writes it: {"translation_mm": [x, y, z], "rotation_deg": [x, y, z]}
// (DESIGN.md: radians inside, degrees at the edges; the unit in the key).
nlohmann::json pose_delta_json(const double delta_mm_rad[6]);

// {"cycles", "translation_mm": {"mean": [x,y,z], "sd": [...]}, "rotation_deg": {...},
//  "error_3d_mm": {"mean", "p95", "max"}, "share_over_1mm", "share_over_2mm",
//  "beam_on": {"cycles", "share_over_1mm", "share_over_2mm"}}
nlohmann::json to_json(const loop::TargetResidualReport& r);
// {"commands", "p50", "p95", "p99", "max"} (ms)
nlohmann::json to_json(const loop::CommandLatencyReport& r);
// {"commands", "arrive": {"p50", "p95", "p99", "max"}, "preprocess", "register", "gate",
//  "write", "acknowledge", "total"} (ms): latency_chain.hpp's links
nlohmann::json to_json(const loop::LatencyChainReport& r);
// {"p50", "p95", "p99", "max"} (ms): one link's quantiles
nlohmann::json to_json(const loop::LinkLatency& l);

}  // namespace lftrack::records
