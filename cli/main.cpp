// lftrack: the program. Exceptions stop here; commands report failures as a Status.

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <exception>

#include "cli_commands.hpp"
#include "lftrack/tracking/version.hpp"

int main(int argc, char** argv) {
  auto logger = spdlog::stderr_color_mt("lftrack");
  spdlog::set_default_logger(logger);
  spdlog::set_pattern("[%H:%M:%S.%e] %^%l%$: %v");

  CLI::App app{"lftrack: real-time patient tracking for image-guided radiosurgery"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("lftrack ") + lftrack::kVersion);
  bool verbose = false, quiet = false;
  app.add_flag("-v,--verbose", verbose, "More log output");
  app.add_flag("-q,--quiet", quiet, "Only warnings and errors");

  using namespace lftrack::cli;
  const Command info = add_info_command(&app);
  const Command drr = add_drr_command(&app);
  const Command precompute = add_precompute_command(&app);
  CLI::App* scene = app.add_subcommand("scene", "A patient's scene: set up from the treatment plan");
  scene->require_subcommand(1);
  const Command scene_new = add_scene_new_command(scene, argc, argv);
  CLI::App* bench = app.add_subcommand("bench", "Benchmarks measured side by side in one run");
  bench->require_subcommand(1);
  const Command bench_drr = add_bench_drr_command(bench);
  const Command bench_register = add_bench_register_command(bench);
  const Command bench_octree = add_bench_octree_command(bench);
  const Command bench_frames = add_bench_frames_command(bench);
  const Command register_frames = add_register_command(&app);
  CLI::App* study = app.add_subcommand("study", "Studies: many registrations, a CSV, a plot and a summary");
  study->require_subcommand(1);
  const Command capture_range = add_study_capture_range_command(study);
  const Command sensitivity = add_study_sensitivity_command(study);
  const Command trade = add_study_trade_command(study);
  const Command realism = add_study_realism_command(study);
  const Command latency = add_study_latency_command(study);
  const Command surrogate = add_study_surrogate_command(study);
  const Command merge = add_study_merge_command(study);
  const Command submit = add_study_submit_command(study);
  const Command study_status = add_study_status_command(study);
  const Command journal = add_journal_command(&app);
  const Command sim = add_sim_command(&app);
  const Command run_loop = add_run_command(&app);
  const Command replay = add_replay_command(&app);
  CLI::App* serve = app.add_subcommand("serve", "A simulated device as a process of its own, speaking the real protocol");
  serve->require_subcommand(1);
  const Command serve_couch = add_serve_couch_command(serve);
  const Command serve_robot = add_serve_robot_command(serve);
  const Command serve_detectors = add_serve_detectors_command(serve);
  const Command serve_tracker = add_serve_tracker_command(serve);
  CLI::App* calibrate =
      app.add_subcommand("calibrate", "Calibration: X-ray views from a phantom, the couch's axes, a detector's maps");
  calibrate->require_subcommand(1);
  const Command calibrate_views = add_calibrate_views_command(calibrate);
  const Command calibrate_couch = add_calibrate_couch_command(calibrate);
  const Command calibrate_detector = add_calibrate_detector_command(calibrate);
  const Command rt_check = add_rt_check_command(&app);
  const Command commission = add_commission_command(&app, argc, argv);
  CLI::App* qa = app.add_subcommand(
      "qa",
      "Quality assurance a physicist runs: the daily QA and the end-to-end test on the room's phantom, the "
      "detectors' image quality");
  qa->require_subcommand(1);
  const Command qa_daily = add_qa_daily_command(qa);
  const Command qa_e2e = add_qa_e2e_command(qa);
  const Command qa_detector = add_qa_detector_command(qa);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; every usage error (an unknown option, a value that does not
    // parse or is out of range) exits 2, the shell's convention, after CLI11's message.
    return app.exit(e) == 0 ? 0 : 2;
  }
  spdlog::set_level(quiet ? spdlog::level::warn : verbose ? spdlog::level::debug : spdlog::level::info);

  try {
    lftrack::Status status;
    if (app.got_subcommand("info"))
      status = info();
    else if (app.got_subcommand("drr"))
      status = drr();
    else if (app.got_subcommand("precompute"))
      status = precompute();
    else if (scene->got_subcommand("new"))
      status = scene_new();
    else if (bench->got_subcommand("drr"))
      status = bench_drr();
    else if (bench->got_subcommand("register"))
      status = bench_register();
    else if (bench->got_subcommand("octree"))
      status = bench_octree();
    else if (bench->got_subcommand("frames"))
      status = bench_frames();
    else if (app.got_subcommand("register"))
      status = register_frames();
    else if (study->got_subcommand("capture-range"))
      status = capture_range();
    else if (study->got_subcommand("sensitivity"))
      status = sensitivity();
    else if (study->got_subcommand("trade"))
      status = trade();
    else if (study->got_subcommand("realism"))
      status = realism();
    else if (study->got_subcommand("latency"))
      status = latency();
    else if (study->got_subcommand("surrogate"))
      status = surrogate();
    else if (study->got_subcommand("merge"))
      status = merge();
    else if (study->got_subcommand("submit"))
      status = submit();
    else if (study->got_subcommand("status"))
      status = study_status();
    else if (app.got_subcommand("journal"))
      status = journal();
    else if (app.got_subcommand("sim"))
      status = sim();
    else if (app.got_subcommand("run"))
      status = run_loop();
    else if (app.got_subcommand("replay"))
      status = replay();
    else if (serve->got_subcommand("couch"))
      status = serve_couch();
    else if (serve->got_subcommand("robot"))
      status = serve_robot();
    else if (serve->got_subcommand("detectors"))
      status = serve_detectors();
    else if (serve->got_subcommand("tracker"))
      status = serve_tracker();
    else if (calibrate->got_subcommand("views"))
      status = calibrate_views();
    else if (calibrate->got_subcommand("couch"))
      status = calibrate_couch();
    else if (calibrate->got_subcommand("detector"))
      status = calibrate_detector();
    else if (app.got_subcommand("rt-check"))
      status = rt_check();
    else if (app.got_subcommand("commission"))
      status = commission();
    else if (qa->got_subcommand("daily"))
      status = qa_daily();
    else if (qa->got_subcommand("e2e"))
      status = qa_e2e();
    else if (qa->got_subcommand("detector"))
      status = qa_detector();
    if (!status.ok()) {
      // A message may quote what a file or a user wrote (a DICOM name, a path): control characters
      // other than line breaks are shown as '?', never sent to the terminal.
      std::string message = status.message();
      for (char& ch : message)
        if ((static_cast<unsigned char>(ch) < 0x20 && ch != '\n' && ch != '\t') || ch == 0x7f) ch = '?';
      spdlog::error("{}", message);
      return 1;
    }
    // What a command printed must have reached its reader: a full disk or a closed pipe under
    // standard output is a failure, not a success with nothing written (issue 50 probe:
    // `journal export J > /dev/full` exited 0).
    if (std::fflush(stdout) != 0 || std::ferror(stdout)) {
      spdlog::error("cannot write standard output: {}", std::strerror(errno));
      return 1;
    }
  } catch (const std::exception& e) {
    spdlog::critical("unexpected error: {}", e.what());
    return 3;
  }
  return 0;
}
