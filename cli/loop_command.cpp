// `lftrack sim`, `run` and `replay`: one loop command in three modes (loop_command.hpp). No
// simulator here: `run` and `replay` are made here and run with none; the program (cmd_sim.cpp)
// passes its own to `sim`'s LoopCommand::run.

#include <signal.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>

#include "lftrack/loop/allocation_counter.hpp"
#include "lftrack/loop/realtime_setup.hpp"
#include "lftrack/qa/qa_report.hpp"
#include "lftrack/records/loop_json.hpp"
#include "lftrack/session/loop_session.hpp"
#include "lftrack/session/patient_setup.hpp"
#include "lftrack/session/preflight.hpp"
#include "lftrack/session/scene_default_plans.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/session/scene_exposure.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "loop_command.hpp"
#include "run_summary.hpp"

namespace lftrack::cli {

using session::apply_default_plans;
using session::archived_frame_plans;
using session::check_session_hil;
using session::check_session_options;
using session::check_session_surrogate;
using session::describe_actuator;
using session::describe_exposure;
using session::describe_frames;
using session::frames_are_simulated;
using session::HilProtocol;
using session::load_scene;
using session::LoopSession;
using session::LoopSessionOptions;
using session::PreflightReport;
using session::prepare_scene;
using session::run_preflight;
using session::Scene;
using session::SessionDevices;
using session::simulated_accuracy_caveat;

using loop::apply_realtime_setup;
using loop::check_auto_resume_s;
using loop::check_realtime_setup;
using loop::ImagingSpec;
using loop::LoopSpec;
using loop::process_allocation_count;
using loop::realtime_not_applied;
using loop::RealtimeReport;
using loop::RealtimeSpec;

using watch::IgtlOptions;
using watch::IgtlServer;
using watch::MonitorOptions;
using watch::MonitorServer;
using watch::parse_listen_address;

using records::to_json;

namespace {

// --imaging, --xray-hz and --period-ms on the scene, checked as the scene's own values are. A new
// period keeps the budgets' shares of it and the prediction's span in seconds.
Status override_imaging(const LoopCommandOptions& o, Scene* scene) {
  // CLI11's ranges let NaN through (every comparison with it is false).
  if (o.xray_hz && !std::isfinite(*o.xray_hz)) return invalid_argument("--xray-hz must be a finite number");
  if (o.period_ms && !std::isfinite(*o.period_ms))
    return invalid_argument("--period-ms must be a finite number");
  ImagingSpec& imaging = scene->loop.imaging;
  if (!o.imaging.empty())
    imaging.mode = o.imaging == "model" ? ImagingSpec::Mode::kModel : ImagingSpec::Mode::kEveryCycle;
  if (o.xray_hz) imaging.xray_hz = *o.xray_hz;
  if (o.period_ms) {
    LoopSpec& loop = scene->loop;
    const double scale = *o.period_ms / loop.period_ms;
    loop.registration_budget_ms *= scale;
    loop.acquire_timeout_ms *= scale;
    loop.prediction_cycles =
        std::max(loop.prediction_cycles > 1 ? 2 : 0, int(std::lround(loop.prediction_cycles / scale)));
    loop.period_ms = *o.period_ms;
  }
  if (o.xray_hz && !imaging.model_mode())
    return invalid_argument("--xray-hz: imaging every cycle takes a pair every period; add --imaging model");
  if (imaging.model_mode() && scene->surrogate.source.empty())
    return invalid_argument("--imaging model: the scene " + scene->source +
                            " has no `surrogate` section to follow");
  const double loop_hz = 1e3 / scene->loop.period_ms;
  if (imaging.model_mode() && imaging.xray_hz > loop_hz)
    return invalid_argument(fmt::format("{} {:g} is above the loop's rate ({:g} Hz{})",
                                        o.xray_hz ? "--xray-hz" : "the scene's tracking.imaging.xray_hz",
                                        imaging.xray_hz, loop_hz, o.period_ms ? ", --period-ms" : ""));
  return {};
}

std::atomic<LoopSession*> g_session{nullptr};

extern "C" void on_interrupt(int) {
  if (LoopSession* s = g_session.load()) s->request_stop();
}

// The default journal: <folder>/journal-YYYYmmdd-HHMMSS.lfj (local time); JournalWriter takes
// -2, -3, ... when a run in the same second has claimed it (add_suffix).
std::string timestamped_journal(const std::string& folder) {
  const std::time_t now = std::time(nullptr);
  std::tm local{};
  localtime_r(&now, &local);
  char stamp[32];
  std::strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", &local);
  return (std::filesystem::path(folder) / (std::string("journal-") + stamp + ".lfj")).string();
}

// CLI check of --auto-resume at parse time (the text, before it becomes a double).
std::string check_auto_resume_text(const std::string& text) {
  char* end = nullptr;
  const double s = std::strtod(text.c_str(), &end);
  if (end == text.c_str() || *end != '\0') return "'" + text + "' is not a number of seconds";
  return check_auto_resume_s(s).ok() ? std::string()
                                     : "'" + text +
                                           "' is not from 0 to 3600 seconds (NaN, infinite and "
                                           "negative values are refused)";
}

// Where the watchers listen, on standard output (standard error with --json, which keeps standard
// output for the summary), flushed at once: a script or a test starting lftrack reads the port.
// --monitor-token-quiet (a service, whose output goes to the system journal): the token is named
// by its file only.
void announce_watchers(const LoopSession& session, bool json, bool token_quiet) {
  FILE* to = json ? stderr : stdout;
  if (const MonitorServer* m = session.monitor()) {
    std::fprintf(to, "monitor: %s (view only)\n", m->url().c_str());
    if (token_quiet)
      std::fprintf(to, "monitor: operator token in %s (mode 0600); to act, open %s#token=<the token>\n",
                   m->token_file().c_str(), m->url().c_str());
    else
      std::fprintf(to, "monitor: operator token %s (also in %s, mode 0600); to act, open %s#token=%s\n",
                   m->token().c_str(), m->token_file().c_str(), m->url().c_str(), m->token().c_str());
  }
  if (const IgtlServer* i = session.igtl())
    std::fprintf(to,
                 "igtl: OpenIGTLink server on port %d (TRANSFORM T_room_from_ct and Correction, STATUS)\n",
                 i->port());
  std::fflush(to);
}

Status run(const LoopCommandOptions& o, const session::RoomSimulator* simulator) {
  // The scene's own devices, driven as in the room: `run`, or `sim --room` (a room scene whose
  // detectors are the simulator's). Start-up checks, the real clock, no unattended operator.
  const bool room = o.mode == LoopMode::kRun || o.room;
  // The options that need no scene first: a bad path or value is refused before the CT is
  // loaded and the light fields are built (minutes), and before anything is created.
  LoopSessionOptions so;
  so.cycles = o.cycles;
  so.simulated_clock = o.fast;
  so.status_line = !o.json && ::isatty(STDERR_FILENO) == 1;
  so.announce_holds = !so.status_line;
  so.terminal_operator = ::isatty(STDIN_FILENO) == 1;
  if (o.journal_named) {
    so.journal = o.journal;  // '' for none
    so.journal_options.overwrite = o.overwrite;
  } else {
    so.journal = timestamped_journal(o.journal_folder);
    so.journal_options.add_suffix = true;  // a run in the same second takes -2, -3, ...
  }
  so.overwrite_archive = o.overwrite;
  so.control_socket = o.control;
  so.auto_resume_s = o.auto_resume_s;
  so.light_field_dir = o.lf_dir;
  so.archive = o.archive;
  so.replay_sequence = o.sequence;
  // The simulator, where the program gives one (`sim`), makes the simulated room: every device,
  // or with --room a room scene's simulated detectors beside its served couch (sim.couch_link).
  // `run` and `replay` have none: the session refuses a simulated device there, before any light
  // field is built.
  so.simulator = simulator;
  if (o.hil == "modbus") so.hil = HilProtocol::kModbus;
  if (o.hil == "can") so.hil = HilProtocol::kCan;
  so.allocation_count = &process_allocation_count;
  if (!o.monitor.empty()) {
    auto listen = parse_listen_address(o.monitor);
    if (!listen.ok()) return listen.status().with_context("--monitor");
    MonitorOptions m;
    m.listen = *listen;
    m.extra_origins = o.monitor_origins;
    m.token_file = o.monitor_token_file;
    m.token_dir = o.journal_folder;  // out/sim, out/run or out/replay
    so.monitor = m;
  }
  if (!o.igtl.empty()) {
    auto listen = parse_listen_address(o.igtl);
    if (!listen.ok()) return listen.status().with_context("--igtl");
    IgtlOptions i;
    i.listen = *listen;
    so.igtl = i;
  }
  LFTRACK_RETURN_IF_ERROR(check_session_options(so));

  auto scene = load_scene(o.scene.scene);
  if (!scene.ok()) return scene.status();
  LFTRACK_RETURN_IF_ERROR(override_imaging(o, &*scene));
  if (room) {
    so.devices = SessionDevices::kScene;
    std::string frames = scene->detectors.empty() ? "none" : describe_frames(scene->detectors[0].frames);
    for (std::size_t i = 1; i < scene->detectors.size(); ++i)
      frames += ", " + describe_frames(scene->detectors[i].frames);
    spdlog::info("{}: detectors {}; actuator {}", scene->name, frames, describe_actuator(scene->actuator));
  }
  LFTRACK_RETURN_IF_ERROR(check_session_surrogate(*scene, so));  // before the CT and light fields
  LFTRACK_RETURN_IF_ERROR(check_session_hil(*scene, so));
  RealtimeSpec rt = scene->loop.realtime;
  if (!o.rt.empty()) rt.enforce = o.rt == "enforce";
  // Real-time set-up first, so every thread made afterwards inherits the policy and affinity:
  // the registration's workers run at the cycle's priority; the simulated detectors drop one
  // level below it, the journal and archive writers to SCHED_OTHER (realtime_setup.hpp). Only
  // for runs on the real clock in enforce mode: an offline run (--fast) on SCHED_FIFO would spin
  // every core at real-time priority and starve the host, for no timing it needs; ignore means
  // none of it; and `run --check` applies nothing, it says whether the set-up could be applied.
  const bool real_clock = room || !o.fast;
  Result<RealtimeReport> report = realtime_not_applied("offline run on a simulated clock");
  if (real_clock && !rt.enforce)
    report = realtime_not_applied(o.rt == "ignore" ? "--rt ignore" : "loop.realtime.mode: ignore");
  else if (real_clock && o.check)
    report = check_realtime_setup(rt);
  else if (real_clock)
    report = apply_realtime_setup(rt);
  // `run` lists a failed set-up among its start-up checks; the others stop here.
  if (!report.ok() && !room) return report.status();
  if (report.ok()) {
    for (const std::string& w : report->warnings) spdlog::warn("real-time set-up (ignored): {}", w);
    spdlog::info("real-time set-up: {}", report->summary());
  }

  tracking::ThreadPool pool(o.scene.threads);
  // An archive may hold any detector's frames: the plans the scene leaves open are those for
  // archived frames, whatever its detectors say (scene_default_plans.hpp).
  if (o.mode == LoopMode::kReplay && !o.sequence.empty())
    apply_default_plans(archived_frame_plans(), &*scene);
  auto prepared = prepare_scene(*scene, o.scene.ct, &pool);
  if (!prepared.ok()) return prepared.status();
  if ((o.mode == LoopMode::kSim && !room) || (room && frames_are_simulated(prepared->scene)))
    spdlog::info("{}: simulated detectors, {}", prepared->scene.name, describe_exposure(*prepared));
  if (room) {
    // The start-up checks before the first beam: every reason at once, nothing built or moved.
    PreflightReport checks = run_preflight(*prepared, so, report, o.rt == "ignore");
    checks.items.push_back(qa::daily_qa_item(prepared->scene));  // today's QA of the room (issue 59)
    if (o.check || !checks.passed())
      std::printf("pre-treatment checklist, %s:\n%s", prepared->scene.name.c_str(),
                  checks.checklist().c_str());
    if (!checks.passed())
      return failed_precondition(
          std::string(o.mode == LoopMode::kRun ? "lftrack run" : "lftrack sim --room") +
          " refuses to start; the start-up checks failed:\n" + checks.failures());
    if (o.check) return {};
  }
  if (!so.journal.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(so.journal.parent_path(), ec);
  }
  auto session = LoopSession::create(*prepared, so, &pool);
  if (!session.ok()) return session.status();
  if (const drivers::ReplayFrameSource* replay = (*session)->replay())
    spdlog::info("{}: replaying {} pairs from {}{}", prepared->scene.name, replay->pairs(),
                 replay->sequence().directory.string(),
                 o.fast ? " as fast as possible" : " at the recorded pace");
  else
    spdlog::info("{}: {} cycles at {} ms{}{}", prepared->scene.name, o.cycles, prepared->scene.loop.period_ms,
                 o.fast ? " on a simulated clock" : "",
                 so.terminal_operator ? "; keys: r resume, s stop, q quit" : "");
  announce_watchers(**session, o.json, o.monitor_token_quiet);
  const std::string journal = (*session)->journal_path().string();  // the file written, suffix included
  g_session.store(session->get());
  struct sigaction action {};
  action.sa_handler = on_interrupt;
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
  sigaction(SIGHUP, &action, nullptr);  // a closed terminal ends the run as Ctrl-C does, summary and all
  auto summary = (*session)->run();
  g_session.store(nullptr);
  if (!summary.ok()) return summary.status();
  if (!summary->journal_error.empty()) spdlog::error("{}", summary->journal_error);
  if (o.json) {
    nlohmann::json j = to_json(*summary);
    j["scene"] = prepared->scene.name;
    if (const std::string caveat = simulated_accuracy_caveat(*prepared->ct);
        !caveat.empty() && frames_are_simulated(prepared->scene))
      j["accuracy_caveat"] = caveat;
    j["period_ms"] = prepared->scene.loop.period_ms;
    const Scene::DefaultedPlans& defaulted = prepared->scene.defaulted_plans;
    j["plans"] = {{"align", prepared->scene.loop.align_plan},
                  {"track", prepared->scene.loop.track_plan},
                  {"similarity", prepared->scene.registration.similarity},
                  {"align_default", defaulted.align},
                  {"track_default", defaulted.track}};
    if (defaulted.align || defaulted.track) j["plans"]["default_because"] = defaulted.because;
    j["simulated_clock"] = o.fast;
    j["realtime"] = report->summary();
    if (!journal.empty()) j["journal"] = journal;
    add_device_counters(**session, o.archive, &j);
    std::printf("%s\n", j.dump(2).c_str());
  } else {
    print_summary(*summary);
    if (const std::string caveat = simulated_accuracy_caveat(*prepared->ct);
        !caveat.empty() && frames_are_simulated(prepared->scene))
      std::printf("note: %s\n", caveat.c_str());
    print_device_counters(**session, o.archive);
    if (!journal.empty())
      std::printf("journal: %s (lftrack journal export %s)\n", journal.c_str(), journal.c_str());
  }
  if (!summary->journal_error.empty()) return io_error(summary->journal_error);
  return {};
}

}  // namespace

LoopCommand add_loop_command(CLI::App* parent, const char* name, const char* description, LoopMode mode) {
  auto o = std::make_shared<LoopCommandOptions>();
  o->mode = mode;
  if (mode != LoopMode::kSim) o->cycles = 0;
  if (mode == LoopMode::kReplay) o->journal_folder = "out/replay";
  if (mode == LoopMode::kRun) o->journal_folder = "out/run";
  CLI::App* app = parent->add_subcommand(name, description);
  add_scene_options(app, &o->scene);
  if (mode == LoopMode::kReplay)
    app->add_option("--sequence", o->sequence, "Archived frame sequence (a directory with index.csv)")
        ->required()
        ->check(not_empty());
  CLI::Option* cycles =
      app->add_option("--cycles", o->cycles,
                      mode == LoopMode::kReplay ? "Cycles to run (0: to the end of the sequence)"
                      : mode == LoopMode::kSim  ? "Cycles to run (0: until quit; with --room, 0 by default)"
                                                : "Cycles to run (0: until quit)")
          ->capture_default_str()
          ->check(CLI::Range(std::int64_t(0), std::int64_t(1000000000)));
  app->add_flag("--json", o->json, "Print the summary as JSON");
  if (mode == LoopMode::kSim)
    app->add_flag("--fast", o->fast,
                  "As fast as possible on a simulated clock, on which a cycle's work takes no time: the same "
                  "seed gives the same run whatever the host's load (no real-time set-up)");
  if (mode == LoopMode::kReplay)
    app->add_flag("--fast", o->fast, "As fast as possible on a simulated clock (default: the recorded pace)");
  CLI::Option* room = nullptr;
  if (mode == LoopMode::kSim)
    room =
        app->add_flag("--room", o->room,
                      "The scene's own devices as `lftrack run` drives them (start-up checks, real clock), "
                      "its detectors with `frames: sim` and the patient made by the simulator: a room of "
                      "served twins (scenes/room/), or the QA phantom's room")
            ->disable_flag_override();  // `--room=0` would be given (for --check's needs), yet be off
  if (mode != LoopMode::kReplay) {
    CLI::Option* check = app->add_flag(
        "--check", o->check,
        "Only the start-up checks: devices, calibrations, light fields, real-time set-up; print the "
        "pre-treatment checklist (exit 1 if any fails)");
    check->disable_flag_override();  // `--check=0` would be given, yet not ask for the checks
    check->excludes(app->get_option("--json"));  // the checklist is text (no summary to print)
    if (room != nullptr) check->needs(room);
  }
  if (mode == LoopMode::kSim)
    app->add_option("--hil", o->hil,
                    "Hardware in the loop: the virtual couch behind a Modbus TCP server on 127.0.0.1 "
                    "(modbus), or a virtual robot on a CAN link (can), commanded through the real driver")
        ->check(CLI::IsMember({"modbus", "can"}));
  if (mode == LoopMode::kSim) {
    app->add_option(
           "--imaging", o->imaging,
           "Instead of the scene's tracking.imaging.mode: a pair every cycle, or X-ray pairs at --xray-hz "
           "and the surrogate's correlation model between them (the scene needs a `surrogate`)")
        ->check(CLI::IsMember({"every_cycle", "model"}));
    app->add_option("--xray-hz", o->xray_hz, "Instead of the scene's tracking.imaging.xray_hz")
        ->check(CLI::Range(0.05, 100.0));
    app->add_option("--period-ms", o->period_ms,
                    "Instead of the scene's loop.period_ms (its budgets and prediction scaled with it)")
        ->check(CLI::Range(5.0, 1000.0));
  }
  if (mode != LoopMode::kReplay)
    app->add_option("--archive", o->archive,
                    "Archive every frame pair in this directory (the format `lftrack replay` reads)");
  app->add_option("--journal", o->journal,
                  "Journal file ('' for none; default: a new " + o->journal_folder +
                      "/journal-DATE-TIME.lfj); never overwritten");
  app->add_flag("--overwrite", o->overwrite,
                "Replace an existing --journal file, or an earlier lftrack archive in the --archive folder");
  app->add_option("--control", o->control,
                  "Control socket path, mode 0600 (datagrams: 'resume ID', 'reset ID', stop, quit, status)");
  // Not for `run`: in the room only a person ends a HOLD (the session refuses it there too).
  if (mode != LoopMode::kRun)
    app->add_option("--auto-resume", o->auto_resume_s,
                    "An unattended operator resumes this many seconds into each HOLD (0 to 3600)")
        ->check(CLI::Validator(check_auto_resume_text, "SECONDS"));
  app->add_option("--rt", o->rt,
                  "Real-time set-up: enforce or ignore (default: the scene's loop.realtime.mode)")
      ->check(CLI::IsMember({"enforce", "ignore"}));
  app->add_option("--lf-dir", o->lf_dir, "Light-field folder (default out/lightfields/<scene>)");
  CLI::Option* monitor = app->add_option("--monitor", o->monitor,
                                         "Serve the operator's live page on [ADDRESS:]PORT (default address "
                                         "127.0.0.1; port 0: any free one); "
                                         "its actions need the run's token, printed at start")
                             ->check(not_empty());
  app->add_option(
         "--monitor-origin", o->monitor_origins,
         "Another origin (http://HOST:PORT) whose page may act, e.g. the console's name when the page "
         "listens on 0.0.0.0")
      ->check(not_empty())
      ->needs(monitor);
  app->add_option("--monitor-token-file", o->monitor_token_file,
                  "Where the token is stored, mode 0600 (default " + o->journal_folder +
                      "/monitor-ADDRESS-PORT.token); removed at exit")
      ->check(not_empty())
      ->needs(monitor);
  app->add_flag(
         "--monitor-token-quiet", o->monitor_token_quiet,
         "Name the token by its file only, never print it (a service whose output the system journal keeps)")
      ->needs(monitor);
  app->add_option("--igtl", o->igtl,
                  "Serve the registered pose over OpenIGTLink on [ADDRESS:]PORT (3D Slicer's OpenIGTLinkIF "
                  "connects as a client)")
      ->check(not_empty());
  // The room's devices, its operator and its scene as `run` takes them: no simulated clock, no
  // simulated couch in their place, no imaging or period but the scene's.
  if (room != nullptr)
    for (const char* other : {"--fast", "--hil", "--auto-resume", "--imaging", "--xray-hz", "--period-ms"})
      room->excludes(app->get_option(other));
  CLI::Option* journal = app->get_option("--journal");
  LoopCommand command;
  command.app = app;
  command.options = o;
  command.run = [o, journal, cycles](const session::RoomSimulator* simulator) {
    o->journal_named = journal->count() > 0;
    if (o->room && cycles->count() == 0) o->cycles = 0;  // a room runs until stopped, as `run` does
    return run(*o, simulator);
  };
  return command;
}

// `run` drives a room's devices and is given no simulator: a scene whose detectors are simulated
// is refused (`lftrack sim --room` runs it). With lftrack_cli_loop's guard (it links no simulator
// target), this is how `run`'s code path is kept free of simulator code (issue 55).
Command add_run_command(CLI::App* parent) {
  LoopCommand run = add_loop_command(
      parent, "run", "The loop on the scene's devices (real-time set-up as the scene says)", LoopMode::kRun);
  return [run] { return run.run(nullptr); };
}

Command add_replay_command(CLI::App* parent) {
  LoopCommand replay = add_loop_command(
      parent, "replay", "The loop on an archived frame sequence: track and report, no actuator",
      LoopMode::kReplay);
  return [replay] { return replay.run(nullptr); };
}

}  // namespace lftrack::cli
