// What `lftrack sim`, `run` and `replay` print when the loop has ended (run_summary.hpp).

#include "run_summary.hpp"

#include <fmt/format.h>

#include <cstdio>
#include <string>

#include "lftrack/drivers/can_robot.hpp"
#include "lftrack/drivers/modbus_couch.hpp"
#include "lftrack/drivers/replay_frame_source.hpp"
#include "lftrack/loop/frame_archive.hpp"
#include "lftrack/loop/latency_chain.hpp"
#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/watch/igtl_server.hpp"

namespace lftrack::cli {

using loop::FrameArchive;
using loop::kLatencyLinks;
using loop::LatencyLink;
using loop::LoopSummary;
using loop::LoopTransition;
using loop::refusals_text;
using loop::TrackingState;
using session::LoopSession;
using watch::IgtlCounters;
using watch::IgtlServer;

void print_summary(const LoopSummary& s) {
  std::printf("cycles %lld (%s), states: ", static_cast<long long>(s.cycles), s.ended.c_str());
  for (int i = 0; i < 5; ++i)
    if (s.states[std::size_t(i)] > 0)
      std::printf("%s %lld  ", to_string(static_cast<TrackingState>(i)),
                  static_cast<long long>(s.states[std::size_t(i)]));
  std::printf("\n");
  if (s.residual_mean_mm)
    std::printf("residual (true, TRACK cycles): mean %.3f mm, p95 %.3f mm, max %.3f mm\n",
                *s.residual_mean_mm, *s.residual_p95_mm, *s.residual_max_mm);
  if (const auto& t = s.target_residual) {
    std::printf(
        "target (true, TRACK cycles) mean +- SD: x %+.2f +- %.2f, y %+.2f +- %.2f, z %+.2f +- %.2f mm; "
        "rotations %+.2f +- %.2f, %+.2f +- %.2f, %+.2f +- %.2f deg\n",
        t->translation_mean_mm[0], t->translation_sd_mm[0], t->translation_mean_mm[1],
        t->translation_sd_mm[1], t->translation_mean_mm[2], t->translation_sd_mm[2], t->rotation_mean_deg[0],
        t->rotation_sd_deg[0], t->rotation_mean_deg[1], t->rotation_sd_deg[1], t->rotation_mean_deg[2],
        t->rotation_sd_deg[2]);
    std::printf(
        "target 3D error: mean %.2f mm, p95 %.2f mm; TRACK cycles beyond 1 mm %.1f %%, beyond 2 mm %.1f %% "
        "(with the beam on: %.1f %%, %.1f %% of %lld)\n",
        t->error_3d_mean_mm, t->error_3d_p95_mm, 100 * t->share_over_1mm, 100 * t->share_over_2mm,
        100 * t->beam_on_share_over_1mm, 100 * t->beam_on_share_over_2mm,
        static_cast<long long>(t->beam_on_cycles));
  }
  if (const auto& l = s.command_latency)
    std::printf(
        "exposure to actuator acknowledgement: p50 %.1f ms, p95 %.1f ms, p99 %.1f ms, max %.1f ms (%lld "
        "commands%s)\n",
        l->p50_ms, l->p95_ms, l->p99_ms, l->max_ms, static_cast<long long>(l->commands),
        s.simulated_clock ? "; simulated clock: the command deadline, not a measurement" : "");
  if (s.simulated_clock && s.command_latency)
    std::printf("latency chain: n/a (simulated clock: the cycle's work takes no simulated time)\n");
  if (const auto& c = s.latency_chain) {
    std::string links;
    for (int i = 0; i < kLatencyLinks; ++i)
      links += fmt::format("{}{} {:.2f} / {:.2f}", i == 0 ? "" : ", ", key_of(static_cast<LatencyLink>(i)),
                           c->links[std::size_t(i)].p50_ms, c->links[std::size_t(i)].p99_ms);
    std::printf("latency chain, p50 / p99 ms per link (%lld commands): %s\n",
                static_cast<long long>(c->commands), links.c_str());
  }
  std::printf(
      "cycle work: p50 %.1f ms, p95 %.1f ms, p99 %.1f ms, max %.1f ms; overruns %lld (periods skipped "
      "%lld)\n",
      s.cycle_p50_ms, s.cycle_p95_ms, s.cycle_p99_ms, s.cycle_max_ms, static_cast<long long>(s.overruns),
      static_cast<long long>(s.skipped_periods));
  std::printf("registration: p50 %.1f ms, p95 %.1f ms, %.0f evaluations on average; alignment %.0f ms\n",
              s.registration_p50_ms, s.registration_p95_ms, s.evaluations_mean, s.align_ms);
  if (s.verdict_checks > 0)
    std::printf(
        "verdict's NCC check in tracking cycles: %lld checks, p50 %.2f ms, p95 %.2f ms, max %.2f ms\n",
        static_cast<long long>(s.verdict_checks), s.verdict_check_p50_ms, s.verdict_check_p95_ms,
        s.verdict_check_max_ms);
  if (s.view_check_every < 0)
    std::printf("verdict's view check: off (safety.max_view_shift_mm: 0, or one view)\n");
  if (s.view_check_every >= 0) {
    const std::string when =
        s.view_check_every > 0
            ? "alignments and once every " + std::to_string(s.view_check_every) + " tracking cycles"
            : std::string("alignments only");
    std::printf(
        "verdict's view check (each view registered alone; %s): %lld checks, %lld refused, %lld due but out "
        "of time in their cycle; p50 %.1f ms, max %.1f ms\n",
        when.c_str(), static_cast<long long>(s.view_checks), static_cast<long long>(s.view_checks_refused),
        static_cast<long long>(s.view_checks_out_of_time), s.view_check_p50_ms, s.view_check_max_ms);
  }
  std::printf("imaging %s: X-ray pairs %lld (%.1f per minute, %lld early)", s.imaging.c_str(),
              static_cast<long long>(s.xray_pairs), s.pairs_per_minute,
              static_cast<long long>(s.early_pairs));
  if (s.dose_per_pair_mGy > 0)
    std::printf(", skin entrance dose %.1f mGy per minute (%.2f mGy per pair, a stated model)",
                s.dose_mGy_per_minute, s.dose_per_pair_mGy);
  if (s.imaging == "model") {
    std::printf("; cycles from the correlation model %lld, checks %lld, missed %lld",
                static_cast<long long>(s.model_cycles), static_cast<long long>(s.model_checks),
                static_cast<long long>(s.model_misses));
    if (s.model_checks > 0) std::printf(", check error p95 %.2f mm", s.model_check_p95_mm);
    if (!s.model_not_ready.empty())
      std::printf("; the model was not ready at the end: %s", s.model_not_ready.c_str());
  }
  std::printf("\n");
  std::printf("holds %lld, faults %lld, corrections sent %lld", static_cast<long long>(s.holds),
              static_cast<long long>(s.faults), static_cast<long long>(s.commands));
  if (s.allocations_per_cycle)
    std::printf(", heap allocations per steady-state cycle %.3f", *s.allocations_per_cycle);
  std::printf("\n");
  if (s.operator_refused > 0)
    std::printf("operator commands refused or discarded: %lld (%s; journal: operator_refusals)\n",
                static_cast<long long>(s.operator_refused),
                refusals_text(s.operator_refused_by_reason).c_str());
  for (const LoopTransition& t : s.transitions)
    std::printf("  cycle %6lld  %-5s -> %-5s  %s\n", static_cast<long long>(t.cycle), to_string(t.from),
                to_string(t.to), t.reason);
}

void print_device_counters(const LoopSession& session, const std::string& archive_dir) {
  const drivers::ReplayFrameSource* replay = session.replay();
  const FrameArchive* archive = session.archive();
  if (replay != nullptr) {
    const drivers::ReplayCounters& c = replay->counters();
    std::printf(
        "replay: %lld of %zu pairs delivered; frames missing %lld, unreadable %lld, wrong size %lld; "
        "pairs late %lld\n",
        static_cast<long long>(c.pairs_delivered), replay->pairs(), static_cast<long long>(c.missing),
        static_cast<long long>(c.unreadable), static_cast<long long>(c.wrong_size),
        static_cast<long long>(c.late));
  }
  if (archive != nullptr)
    std::printf("frames archived: %llu pairs in %s (lftrack replay --sequence %s), %llu dropped\n",
                static_cast<unsigned long long>(archive->pairs_written()), archive_dir.c_str(),
                archive_dir.c_str(), static_cast<unsigned long long>(archive->pairs_dropped()));
  if (const drivers::ModbusCouch* couch = session.modbus_couch()) {
    const drivers::ModbusCouchCounters c = couch->counters();
    std::printf(
        "hil: %s, %lld requests; timeouts %lld, exceptions %lld, bad replies %lld, disconnects %lld\n",
        couch->endpoint().c_str(), static_cast<long long>(c.requests), static_cast<long long>(c.timeouts),
        static_cast<long long>(c.exceptions), static_cast<long long>(c.bad_replies),
        static_cast<long long>(c.disconnects));
  }
  if (const drivers::CanRobot* robot = session.can_robot()) {
    const drivers::CanRobotCounters& c = robot->counters();
    std::printf(
        "hil: CAN robot, %lld frames out, %lld in (%lld heartbeats, %lld error frames); timeouts %lld, "
        "refused %lld, disconnects %lld, reconnects %lld; faults now: %s; seen: %s\n",
        static_cast<long long>(c.frames_out), static_cast<long long>(c.frames_in),
        static_cast<long long>(c.heartbeats), static_cast<long long>(c.error_frames),
        static_cast<long long>(c.timeouts), static_cast<long long>(c.refused),
        static_cast<long long>(c.disconnects), static_cast<long long>(c.reconnects),
        drivers::describe_can_faults(robot->faults()).c_str(),
        drivers::describe_can_faults(robot->faults_seen()).c_str());
  }
}

void add_device_counters(const LoopSession& session, const std::string& archive_dir, nlohmann::json* j) {
  const drivers::ReplayFrameSource* replay = session.replay();
  const FrameArchive* archive = session.archive();
  if (replay != nullptr) {
    const drivers::ReplayCounters& c = replay->counters();
    (*j)["replay"] = {{"sequence", replay->sequence().directory.string()},
                      {"pairs", replay->pairs()},
                      {"pairs_delivered", c.pairs_delivered},
                      {"missing_frames", c.missing},
                      {"unreadable_frames", c.unreadable},
                      {"wrong_size_frames", c.wrong_size},
                      {"late_pairs", c.late}};
  }
  if (const IgtlServer* igtl = session.igtl()) {
    const IgtlCounters c = igtl->counters();
    (*j)["igtl"] = {{"clients", c.clients_total},
                    {"clients_dropped", c.clients_dropped},
                    {"transforms_sent", c.transforms_sent},
                    {"statuses_sent", c.statuses_sent},
                    {"records_skipped", c.records_skipped}};  // cycles that never reached a client
  }
  if (archive != nullptr)
    (*j)["archive"] = {{"directory", archive_dir},
                       {"pairs_written", archive->pairs_written()},
                       {"pairs_dropped", archive->pairs_dropped()}};
  if (const drivers::ModbusCouch* couch = session.modbus_couch()) {
    const drivers::ModbusCouchCounters c = couch->counters();
    (*j)["hil"] = {{"protocol", "modbus"},         {"endpoint", couch->endpoint()},
                   {"requests", c.requests},       {"timeouts", c.timeouts},
                   {"exceptions", c.exceptions},   {"bad_replies", c.bad_replies},
                   {"disconnects", c.disconnects}, {"reconnects", c.reconnects}};
  }
  if (const drivers::CanRobot* robot = session.can_robot()) {
    const drivers::CanRobotCounters& c = robot->counters();
    (*j)["hil"] = {{"protocol", "can"},
                   {"frames_out", c.frames_out},
                   {"frames_in", c.frames_in},
                   {"heartbeats", c.heartbeats},
                   {"error_frames", c.error_frames},
                   {"timeouts", c.timeouts},
                   {"refused", c.refused},
                   {"disconnects", c.disconnects},
                   {"reconnects", c.reconnects},
                   {"faults", drivers::describe_can_faults(robot->faults())},             // at the end
                   {"faults_seen", drivers::describe_can_faults(robot->faults_seen())}};  // during the run
  }
}

}  // namespace lftrack::cli
