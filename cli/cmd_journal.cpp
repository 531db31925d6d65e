// `lftrack journal export FILE [--csv|--summary]`: every valid record of a journal, in file order, as JSON
// lines (one object per cycle) or CSV on stdout. The reader resynchronises past damage, so a bad
// frame loses only itself.
//
// On stderr, after the records: one warning per bad span (byte offset, length, what was wrong),
// per gap in the cycle counter and per repeated cycle, then a summary line when any was found.
//
// Exit status: 0 when the journal is intact, or when all it lacks is what a crash or the writer
// itself explains: a torn tail (a frame cut by a kill -9, zeros a power loss left) or a gap the
// writer's queue-drop count accounts for (each still warned about). 1 when it is damaged (a bad
// span elsewhere, an unexplained gap, a repeated cycle, a read stopped at a limit): the summary is
// the error, printed after every recoverable record, so a script sees the damage.

#include <spdlog/spdlog.h>

#include <cstdio>
#include <cstring>
#include <iterator>
#include <nlohmann/json.hpp>
#include <string>

#include "cli_commands.hpp"
#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/latency_chain.hpp"
#include "lftrack/loop/loop_summary.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/loop/tracking_accuracy.hpp"
#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/records/journal_reader.hpp"
#include "lftrack/records/loop_json.hpp"
#include "lftrack/session/dicom_registration.hpp"
#include "lftrack/session/scene_fingerprint.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::check_registration_path;
using session::load_scene;
using session::room_frame_of_reference_uid;
using session::scene_ct_dicom_identity;
using session::scene_fingerprint;
using session::SpatialRegistration;
using session::to_hex;
using session::write_spatial_registration;

using loop::BeamWithheld;
using loop::GateDecision;
using loop::GateReason;
using loop::ImagingReason;
using loop::JournalRecord;
using loop::LatencyChain;
using loop::OperatorCommand;
using loop::OperatorRefusal;
using loop::refusals_text;
using loop::SurrogateFault;
using loop::TrackingAccuracy;
using loop::TrackingEvent;
using loop::TrackingState;

using records::JournalBadSpan;
using records::JournalContents;
using records::JournalCycleGap;
using records::JournalCycleRepeat;
using records::pose_delta_json;
using records::read_journal;
using records::to_json;
namespace {

// A code's name, or "unknown N" for a code this build does not know (a newer build's journal, or
// damage the record's checksum did not catch): never a bare "?".
template <class Enum>
std::string code_name(std::uint8_t code, int offset = 0) {
  const char* name = to_string(static_cast<Enum>(code - offset));
  return std::strcmp(name, "?") == 0 ? "unknown " + std::to_string(unsigned{code}) : std::string(name);
}
// Imaging on demand (format 6; "" in earlier journals): why the cycle took a pair, and its check.
std::string imaging_name(std::uint8_t code) {
  return code == 0 ? "" : code_name<ImagingReason>(code, 1);
}
std::string model_check_name(std::uint8_t code) {
  static const char* const kNames[] = {"", "not ready", "agrees", "missed, refitted", "missed again"};
  return code < std::size(kNames) ? kNames[code] : "unknown " + std::to_string(unsigned{code});
}
nlohmann::json imaging_json(const JournalRecord& r) {
  return {{"imaging", imaging_name(r.imaging)},
          {"surrogate_fault", code_name<SurrogateFault>(r.surrogate_fault)},
          {"surrogate_time_ns", r.surrogate_time_ns},
          {"surrogate", {{"amplitude", r.surrogate[0]}, {"rate_per_s", r.surrogate[1]}}},
          {"model_ready", (r.model_flags & 1) != 0},
          {"offset_from_model", (r.model_flags & 2) != 0},
          {"model_pairs", r.model_pairs},
          {"model_prediction_mm", r.model_prediction_mm},
          {"model_check", model_check_name(r.model_check)},
          {"model_check_error_mm", r.model_check_error_mm},
          {"model_fit_rms_mm", r.model_fit_rms_mm},
          {"model_coefficients", r.model_coefficients}};
}

std::string state_name(std::uint8_t s) {
  return code_name<TrackingState>(s);
}
// The event that changed the state in a cycle ("" when none).
std::string event_name(std::uint8_t e) {
  return e == 0 ? "" : code_name<TrackingEvent>(e, 1);
}
// The operator command the loop acted on in a cycle ("" when none).
std::string operator_command_name(std::uint8_t c) {
  return c == 0 ? "" : code_name<OperatorCommand>(c, 1);
}

// The reason of a refusal ("" when none).
std::string refusal_name(std::uint8_t code) {
  return code == 0 ? "" : code_name<OperatorRefusal>(code);
}
nlohmann::json refusals_json(const JournalRecord& r) {
  nlohmann::json j = nlohmann::json::object();
  for (std::size_t i = 1; i < std::size(r.operator_refused_by_reason); ++i)
    if (r.operator_refused_by_reason[i] > 0) j[refusal_name(std::uint8_t(i))] = r.operator_refused_by_reason[i];
  return j;
}
// A journal 6-vector (mm, rad) as CSV columns in mm and degrees.
void print_mm_deg(const double v[6]) {
  for (int i = 0; i < 6; ++i) std::printf(",%.6g", i < 3 ? v[i] : tracking::rad_to_deg(v[i]));
}

void print_csv(const std::vector<JournalRecord>& records) {
  std::printf(
      "cycle,cycle_start_ns,frame_seq_a,frame_seq_b,state,previous_state,gate,reason,"
      "tx_mm,ty_mm,tz_mm,rx_deg,ry_deg,rz_deg,similarity_a,similarity_b,evaluations,registration_ms,"
      "command_sent,cmd_tx_mm,cmd_ty_mm,cmd_tz_mm,cmd_rx_deg,cmd_ry_deg,cmd_rz_deg,"
      "beam_permit,overrun,skipped_periods,dropped_before,true_residual_mm,event,"
      "hold_id,operator_command,operator_refused,operator_refusal,beam_withheld,"
      "operator_first_refusal,operator_refusals,"
      "target_tx_mm,target_ty_mm,target_tz_mm,target_rx_deg,target_ry_deg,target_rz_deg,command_acked_ns,"
      "frame_time_a_ns,frame_time_b_ns,frames_arrived_ns,preprocessed_ns,registered_ns,gated_ns,command_"
      "written_ns,imaging,surrogate_fault,surrogate_time_ns,surrogate_amplitude,surrogate_rate_per_s,model_"
      "ready,"
      "offset_from_model,model_pairs,model_x_mm,model_y_mm,model_z_mm,model_check,model_check_error_mm\n");
  for (const JournalRecord& r : records) {
    std::printf("%llu,%lld,%u,%u,%s,%s,%s,\"%s\"", static_cast<unsigned long long>(r.cycle),
                static_cast<long long>(r.cycle_start_ns), r.frame_sequence[0], r.frame_sequence[1],
                state_name(r.state).c_str(), state_name(r.previous_state).c_str(),
                code_name<GateDecision>(r.gate_decision).c_str(), code_name<GateReason>(r.gate_reason).c_str());
    print_mm_deg(r.pose_delta);
    std::printf(",%.6g,%.6g,%u,%.3f,%d", r.similarity[0], r.similarity[1], r.evaluations, r.registration_ms,
                r.command_sent);
    print_mm_deg(r.command);
    std::printf(",%d,%d,%u,%u,%.4f,\"%s\"", r.beam_permit, r.overrun, r.skipped_periods, r.dropped_before,
                r.true_residual_mm, event_name(r.event).c_str());
    std::printf(",%u,\"%s\",%u,\"%s\",\"%s\",\"%s\",\"%s\"", r.hold_id,
                operator_command_name(r.operator_command).c_str(), unsigned{r.operator_refused},
                refusal_name(r.operator_refusal).c_str(), code_name<BeamWithheld>(r.beam_withheld).c_str(),
                refusal_name(r.operator_first_refusal).c_str(), refusals_text(r.operator_refused_by_reason).c_str());
    print_mm_deg(r.true_target_residual);
    std::printf(",%lld,%lld,%lld,%lld,%lld,%lld,%lld,%lld", static_cast<long long>(r.command_acked_ns),
                static_cast<long long>(r.frame_time_ns[0]), static_cast<long long>(r.frame_time_ns[1]),
                static_cast<long long>(r.frames_arrived_ns), static_cast<long long>(r.preprocessed_ns),
                static_cast<long long>(r.registered_ns), static_cast<long long>(r.gated_ns),
                static_cast<long long>(r.command_written_ns));
    std::printf(",\"%s\",\"%s\",%lld,%.6g,%.6g,%d,%d,%u,%.4f,%.4f,%.4f,\"%s\",%.4f\n",
                imaging_name(r.imaging).c_str(), code_name<SurrogateFault>(r.surrogate_fault).c_str(),
                static_cast<long long>(r.surrogate_time_ns), r.surrogate[0], r.surrogate[1],
                r.model_flags & 1, (r.model_flags >> 1) & 1, r.model_pairs, r.model_prediction_mm[0],
                r.model_prediction_mm[1], r.model_prediction_mm[2], model_check_name(r.model_check).c_str(),
                r.model_check_error_mm);
  }
}

void print_json_lines(const std::vector<JournalRecord>& records) {
  for (const JournalRecord& r : records) {
    nlohmann::json j{{"cycle", r.cycle},
                     {"cycle_start_ns", r.cycle_start_ns},
                     {"frame_sequence", {r.frame_sequence[0], r.frame_sequence[1]}},
                     {"state", state_name(r.state)},
                     {"previous_state", state_name(r.previous_state)},
                     {"gate", code_name<GateDecision>(r.gate_decision)},
                     {"reason", code_name<GateReason>(r.gate_reason)},
                     {"pose_delta", pose_delta_json(r.pose_delta)},
                     {"similarity", r.similarity},
                     {"evaluations", r.evaluations},
                     {"registration_ms", r.registration_ms},
                     {"command_sent", r.command_sent != 0},
                     {"command", pose_delta_json(r.command)},
                     {"readback", pose_delta_json(r.readback)},
                     {"beam_permit", r.beam_permit != 0},
                     {"overrun", r.overrun != 0},
                     {"skipped_periods", r.skipped_periods},
                     {"dropped_before", r.dropped_before},
                     {"true_residual_mm", r.true_residual_mm},
                     {"true_target_residual", pose_delta_json(r.true_target_residual)},
                     {"command_acked_ns", r.command_acked_ns},
                     {"frame_time_ns", {r.frame_time_ns[0], r.frame_time_ns[1]}},
                     {"frames_arrived_ns", r.frames_arrived_ns},
                     {"preprocessed_ns", r.preprocessed_ns},
                     {"registered_ns", r.registered_ns},
                     {"gated_ns", r.gated_ns},
                     {"command_written_ns", r.command_written_ns},
                     {"event", event_name(r.event)},
                     {"hold_id", r.hold_id},
                     {"operator_command", operator_command_name(r.operator_command)},
                     {"operator_refused", r.operator_refused},
                     {"operator_refusal", refusal_name(r.operator_refusal)},
                     {"operator_first_refusal", refusal_name(r.operator_first_refusal)},
                     {"operator_refusals", refusals_json(r)},
                     {"beam_withheld", code_name<BeamWithheld>(r.beam_withheld)},
                     {"imaging", imaging_json(r)}};
    std::printf("%s\n", j.dump().c_str());
  }
}

// One stderr warning per bad span, gap, repeated cycle, and a read that stopped early.
void warn_each_problem(const std::string& file, const JournalContents& c) {
  for (std::size_t i = 0; i < c.bad_spans.size(); ++i) {
    const JournalBadSpan& s = c.bad_spans[i];
    const bool torn_tail = c.torn_tail_bytes > 0 && i + 1 == c.bad_spans.size();
    spdlog::warn("{}: bad span at byte {}, {} bytes: {}{}{}", file, s.offset, s.bytes, s.problem,
                 s.zeros ? " (all zeros)" : "", torn_tail ? "; a torn tail, ignored" : "");
  }
  for (const JournalCycleGap& g : c.gaps) {
    const std::string why =
        g.explained_by_drops ? "; the writer dropped " + std::to_string(g.dropped_before) + " records there"
        : g.after_bad_span   ? "; lost in the bad span before it"
                             : "";
    spdlog::warn("{}: gap: cycle {} (record {}) follows cycle {}, {} cycles missing{}", file, g.next_cycle,
                 g.record_index, g.after_cycle, g.missing_cycles, why);
  }
  for (const JournalCycleRepeat& r : c.repeats)
    spdlog::warn("{}: repeated cycle: cycle {} (record {}) after cycle {}", file, r.cycle, r.record_index,
                 r.highest_before);
  if (!c.stopped.empty()) spdlog::warn("{}: {}", file, c.stopped);
}

// "N bad spans (B bytes), G gaps (M cycles missing), D repeated cycles; R records recovered".
std::string summary(const JournalContents& c) {
  std::uint64_t span_bytes = 0, missing = 0;
  for (const JournalBadSpan& s : c.bad_spans) span_bytes += s.bytes;
  for (const JournalCycleGap& g : c.gaps) missing += g.missing_cycles;
  std::string text = std::to_string(c.bad_spans.size()) + " bad spans (" + std::to_string(span_bytes) +
                     " bytes" + (c.torn_tail_bytes > 0 ? ", the last a torn tail" : "") + "), " +
                     std::to_string(c.gaps.size()) + " gaps (" + std::to_string(missing) +
                     " cycles missing), " + std::to_string(c.repeats.size()) + " repeated cycles; " +
                     std::to_string(c.records.size()) + " records recovered";
  if (!c.stopped.empty()) text += "; reading stopped early";
  return text;
}

struct ExportOptions {
  std::string file;
  bool csv = false;
  bool summary = false;
  std::string dicom_sro;
  SceneOptions scene;
  std::int64_t cycle = -1;  // -1: the last cycle whose registration the gate applied
};

// `--summary`: the run's figures from its records, as the loop's summary computes them (one
// accumulator, tracking_accuracy.hpp): cycles per state, the target residual per room axis and the
// share of TRACK cycles beyond 1 and 2 mm (simulation), the exposure-to-acknowledgement latency.
void print_summary_json(const JournalContents& contents) {
  TrackingAccuracy accuracy(contents.format_version >= 4);
  LatencyChain latency_chain;
  std::array<std::int64_t, 5> states{};
  std::int64_t commands = 0, beam_on = 0;
  for (const JournalRecord& r : contents.records) {
    accuracy.add(r);
    latency_chain.add(r);
    if (r.state < states.size()) ++states[r.state];
    commands += r.command_sent != 0;
    beam_on += r.beam_permit != 0;
  }
  nlohmann::json j;
  j["format_version"] = contents.format_version;
  j["records"] = contents.records.size();
  // The figures are over the records that survived: say what did not (the details on stderr).
  std::uint64_t missing = 0;
  for (const JournalCycleGap& g : contents.gaps) missing += g.missing_cycles;
  j["damaged"] = contents.damaged();
  j["bad_spans"] = contents.bad_spans.size();
  j["cycles_missing"] = missing;
  nlohmann::json per_state;
  for (std::size_t i = 0; i < states.size(); ++i) per_state[state_name(std::uint8_t(i))] = states[i];
  j["states"] = per_state;
  j["commands"] = commands;
  j["beam_on_cycles"] = beam_on;
  const auto target = accuracy.target_residual();
  const auto latency = accuracy.latency();
  j["target_residual"] = target ? to_json(*target) : nlohmann::json(nullptr);
  j["latency_exposure_to_ack_ms"] = latency ? to_json(*latency) : nlohmann::json(nullptr);
  const auto chain = latency_chain.report();
  j["latency_chain_ms"] = chain ? to_json(*chain) : nlohmann::json(nullptr);
  if (contents.format_version == 4) j["note"] = "journal format 4 records no latency chain (format 5 on)";
  if (contents.format_version < 4)
    j["note"] = "journal format " + std::to_string(contents.format_version) +
                " records no target residual per axis and no acknowledgement time";
  std::printf("%s\n", j.dump(2).c_str());
}

// `--dicom-sro FILE`: one cycle's registered pose as a DICOM Spatial Registration object. Only a
// registration the safety gate applied in a cycle that ended in TRACK is exported (a HOLD's or a
// rejected alignment's pose is no registration of record), from an undamaged journal of this
// scene (the header's fingerprint: the same room and CT); the journal holds the pose as a delta
// from the scene's nominal pose, so the scene gives it back as T_room_from_ct.
Status export_dicom(const ExportOptions& o, const JournalContents& contents) {
  LFTRACK_RETURN_IF_ERROR(check_registration_path(o.dicom_sro).with_context("--dicom-sro"));
  if (contents.damaged())
    return corrupt_data(o.file + ": journal damaged (" + summary(contents) + "); no registration exported from it");
  const JournalRecord* chosen = nullptr;
  for (const JournalRecord& r : contents.records) {
    const bool applied = r.gate_decision == static_cast<std::uint8_t>(GateDecision::kApply) &&
                         r.state == static_cast<std::uint8_t>(TrackingState::kTrack);
    if (o.cycle >= 0 && r.cycle == static_cast<std::uint64_t>(o.cycle)) {
      if (!applied)
        return failed_precondition("cycle " + std::to_string(o.cycle) + ": its registration was not applied (gate " +
                                   code_name<GateDecision>(r.gate_decision) + ", reason " +
                                   code_name<GateReason>(r.gate_reason) + ", the cycle ended in " +
                                   state_name(r.state) +
                                   "); export a cycle the gate applied that ended in TRACK");
      chosen = &r;
    }
    if (o.cycle < 0 && applied) chosen = &r;
  }
  if (chosen == nullptr)
    return not_found(o.file + (o.cycle >= 0 ? ": no cycle " + std::to_string(o.cycle)
                                            : std::string(": no cycle whose registration the gate applied")));
  tracking::ThreadPool pool(o.scene.threads);
  auto scene = load_scene(o.scene.scene);
  if (!scene.ok()) return scene.status();
  if (!o.scene.ct.empty()) scene->ct.path = o.scene.ct;
  constexpr std::array<std::uint8_t, 16> kNotRecorded{};
  if (contents.scene_fingerprint == kNotRecorded)
    return failed_precondition(o.file + ": the journal does not record its scene (written before lftrack recorded "
                               "it); its poses cannot be tied to this scene's CT");
  const std::array<std::uint8_t, 16> fingerprint = scene_fingerprint(*scene);
  if (contents.scene_fingerprint != fingerprint)
    return failed_precondition(o.file + ": the journal was written with another room or CT (scene fingerprint " +
                               to_hex(contents.scene_fingerprint) + ", this scene's " + to_hex(fingerprint) +
                               "); give the scene and --ct of the run");
  auto identity = scene_ct_dicom_identity(*scene);  // before the CT's voxels are read
  if (!identity.ok()) return identity.status().with_context("--dicom-sro");
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  Eigen::Map<const tracking::Vector6d> delta(chosen->pose_delta);
  SpatialRegistration reg;
  reg.T_room_from_ct = tracking::apply_delta(prepared->nominal_T_room_from_ct, tracking::PoseDelta::from_vector(delta),
                                             prepared->registration_origin_room_mm());
  reg.room_frame_of_reference_uid = room_frame_of_reference_uid(prepared->scene);
  reg.description = "lftrack journal cycle " + std::to_string(chosen->cycle);
  LFTRACK_RETURN_IF_ERROR(write_spatial_registration(o.dicom_sro, *identity, reg));
  std::printf("wrote %s: cycle %llu's registration (T_room_from_ct) of the CT series %s\n", o.dicom_sro.c_str(),
              static_cast<unsigned long long>(chosen->cycle), identity->series_uid.c_str());
  return {};
}

}  // namespace

Command add_journal_command(CLI::App* parent) {
  auto* journal = parent->add_subcommand("journal", "Read cycle journals");
  journal->require_subcommand(1);
  auto* app = journal->add_subcommand(
      "export", "Print a journal's records as JSON lines or CSV, or one registration as a DICOM file");
  auto o = std::make_shared<ExportOptions>();
  app->add_option("file", o->file, "Journal file")->required();
  CLI::Option* csv = app->add_flag("--csv", o->csv, "CSV instead of JSON lines");
  CLI::Option* dicom = app->add_option("--dicom-sro", o->dicom_sro,
                                       "Write one cycle's registration as a DICOM Spatial Registration object "
                                       "referencing the scene's planning CT (a DICOM series); needs --scene")
                           ->check(not_empty())
                           ->excludes(csv);
  app->add_flag(
         "--summary", o->summary,
         "Print the run's figures instead of the records (JSON): cycles per state, commands, the "
         "target's true residual per room axis with the share of TRACK cycles beyond 1 and 2 mm "
         "(simulation), exposure-to-acknowledgement latency p50/p95/p99, and link by link (real clock)")
      ->excludes(csv)
      ->excludes(dicom);
  add_scene_options(app, &o->scene);
  app->add_option("--cycle", o->cycle, "With --dicom-sro: the cycle (default: the last one the gate applied)")
      ->check(CLI::Range(std::int64_t(0), std::int64_t(1) << 50))
      ->needs(dicom);
  return [o, app]() -> Status {
    if (!app->parsed()) return {};
    auto contents = read_journal(o->file);
    if (!contents.ok()) return contents.status();
    if (!o->dicom_sro.empty()) {
      warn_each_problem(o->file, *contents);
      return export_dicom(*o, *contents);
    }
    if (o->summary)
      print_summary_json(*contents);
    else if (o->csv)
      print_csv(contents->records);
    else
      print_json_lines(contents->records);
    std::fflush(stdout);
    warn_each_problem(o->file, *contents);
    if (contents->damaged()) return corrupt_data(o->file + ": journal damaged: " + summary(*contents));
    if (!contents->bad_spans.empty() || !contents->gaps.empty())
      spdlog::warn("{}: journal incomplete, not damaged: {}", o->file, summary(*contents));
    return {};
  };
}

}  // namespace lftrack::cli
