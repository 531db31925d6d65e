// `lftrack journal export FILE [--csv]`: every complete record of a journal as JSON lines (one
// object per cycle) or CSV; a torn tail is reported on stderr and ignored.

#include <spdlog/spdlog.h>

#include <cstdio>
#include <nlohmann/json.hpp>

#include "cli_commands.hpp"
#include "lftrack/host/journal.hpp"
#include "lftrack/host/safety_gate.hpp"
#include "lftrack/host/tracking_states.hpp"

namespace lftrack::host::cli {

Command add_journal_command(CLI::App* parent) {
  auto* journal = parent->add_subcommand("journal", "Read cycle journals");
  journal->require_subcommand(1);
  auto* app = journal->add_subcommand("export", "Print a journal's records as JSON lines or CSV");
  struct Options {
    std::string file;
    bool csv = false;
  };
  auto o = std::make_shared<Options>();
  app->add_option("file", o->file, "Journal file")->required();
  app->add_flag("--csv", o->csv, "CSV instead of JSON lines");
  return [o, app]() -> Status {
    if (!app->parsed()) return {};
    auto contents = read_journal(o->file);
    if (!contents.ok()) return contents.status();
    if (!contents->note.empty()) spdlog::warn("{}: {} ({} bytes)", o->file, contents->note, contents->torn_tail_bytes);
    auto state = [](std::uint8_t s) { return to_string(static_cast<TrackingState>(s)); };
    // The event that changed the state in a cycle ("" when none).
    auto event = [](std::uint8_t e) { return e == 0 ? "" : to_string(static_cast<TrackingEvent>(e - 1)); };
    if (o->csv) {
      std::printf(
          "cycle,cycle_start_ns,frame_seq_a,frame_seq_b,state,previous_state,gate,reason,tx_mm,ty_mm,tz_mm,rx_rad,ry_rad,"
          "rz_rad,similarity_a,similarity_b,evaluations,registration_ms,command_sent,cmd_tx_mm,cmd_ty_mm,cmd_tz_mm,"
          "cmd_rx_rad,cmd_ry_rad,cmd_rz_rad,beam_permit,overrun,skipped_periods,dropped_before,true_residual_mm,event\n");
      for (const JournalRecord& r : contents->records) {
        std::printf("%llu,%lld,%u,%u,%s,%s,%s,\"%s\"", static_cast<unsigned long long>(r.cycle),
                    static_cast<long long>(r.cycle_start_ns), r.frame_sequence[0], r.frame_sequence[1], state(r.state),
                    state(r.previous_state), to_string(static_cast<GateDecision>(r.gate_decision)),
                    to_string(static_cast<GateReason>(r.gate_reason)));
        for (double v : r.pose_delta) std::printf(",%.6g", v);
        std::printf(",%.6g,%.6g,%u,%.3f,%d", r.similarity[0], r.similarity[1], r.evaluations, r.registration_ms,
                    r.command_sent);
        for (double v : r.command) std::printf(",%.6g", v);
        std::printf(",%d,%d,%u,%u,%.4f,\"%s\"\n", r.beam_permit, r.overrun, r.skipped_periods, r.dropped_before,
                    r.true_residual_mm, event(r.event));
      }
      return {};
    }
    for (const JournalRecord& r : contents->records) {
      nlohmann::json j{{"cycle", r.cycle},
                       {"cycle_start_ns", r.cycle_start_ns},
                       {"frame_sequence", {r.frame_sequence[0], r.frame_sequence[1]}},
                       {"state", state(r.state)},
                       {"previous_state", state(r.previous_state)},
                       {"gate", to_string(static_cast<GateDecision>(r.gate_decision))},
                       {"reason", to_string(static_cast<GateReason>(r.gate_reason))},
                       {"pose_delta", r.pose_delta},
                       {"similarity", r.similarity},
                       {"evaluations", r.evaluations},
                       {"registration_ms", r.registration_ms},
                       {"command_sent", r.command_sent != 0},
                       {"command", r.command},
                       {"readback", r.readback},
                       {"beam_permit", r.beam_permit != 0},
                       {"overrun", r.overrun != 0},
                       {"skipped_periods", r.skipped_periods},
                       {"dropped_before", r.dropped_before},
                       {"true_residual_mm", r.true_residual_mm},
                       {"event", event(r.event)}};
      std::printf("%s\n", j.dump().c_str());
    }
    return {};
  };
}

}  // namespace lftrack::host::cli
