#pragma once
// What `lftrack sim`, `run` and `replay` print when the loop has ended (cmd_sim.cpp): the loop's
// summary as text, and the counters of the session's devices (the replayed sequence, the frame
// archive in `archive_dir`, the OpenIGTLink server, the Modbus couch or CAN robot) as text or as
// keys of the JSON summary.

#include <nlohmann/json.hpp>
#include <string>

#include "lftrack/loop/loop_summary.hpp"
#include "lftrack/session/loop_session.hpp"

namespace lftrack::cli {

void print_summary(const loop::LoopSummary& summary);
void print_device_counters(const session::LoopSession& session, const std::string& archive_dir);
void add_device_counters(const session::LoopSession& session, const std::string& archive_dir,
                         nlohmann::json* j);

}  // namespace lftrack::cli
