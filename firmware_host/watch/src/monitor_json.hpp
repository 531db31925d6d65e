#pragma once
// The monitor's JSON (monitor_server.hpp): GET /api/state, and the events of GET /api/events.
// Field names say their units; angles are degrees (display), times milliseconds.

#include <nlohmann/json.hpp>

#include "lftrack/watch/cycle_hub.hpp"

namespace lftrack::watch {

// The current snapshot: cycle, state, the gate's last decision and reason, the registered
// offset and the correction sent, similarity, the correction's latency chain (latency_chain.hpp;
// null without one), hold id, counts, recent transitions.
nlohmann::json state_json(const HubStatus& status, const HubOptions& options);
// Trace points as rows: [cycle, registered, tx, ty, tz (mm), rx, ry, rz (deg), true residual
// (mm, -1 outside simulation), similarity A, similarity B, registration ms, state, command sent].
nlohmann::json trace_json(const std::vector<TracePoint>& points);
// Display images, pixels as base64 of 8-bit grey rows.
nlohmann::json images_json(const DisplayImages& images);

}  // namespace lftrack::watch
