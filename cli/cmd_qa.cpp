// `lftrack qa daily`: the room's daily QA on its phantom (lftrack/qa/daily_qa.hpp), each check
// printed as it ends, then a dated report (JSON and HTML) in the QA folder. Exit 0: passed; 1:
// a check failed (the reasons printed) or the QA could not run.

#include <signal.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <functional>
#include <vector>

#include <Eigen/Core>

#include "cli_commands.hpp"
#include "frame_folders.hpp"
#include "lftrack/qa/daily_qa.hpp"
#include "lftrack/qa/qa_report.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::DetectorSpec;
using session::PreparedScene;
using session::Scene;
namespace {

// The operator's Ctrl-C (or SIGTERM) during a daily QA: the QA ends early and safely (its couch
// sent back, its report written: DailyQaOptions::interrupted). Another Ctrl-C while it ends is
// not a quit (a nervous double tap would leave the couch displaced and no report): SIGQUIT
// (Ctrl-\ on a terminal) quits at once.
std::atomic<bool> g_qa_interrupted{false};
extern "C" void on_qa_interrupt(int) {
  const bool again = g_qa_interrupted.exchange(true);
  constexpr char kFirst[] =
      "\ninterrupted: the QA ends after this step (a room's couch goes back to where it stood before the "
      "shift; Ctrl-\\ quits at once, leaving it where it is)\n";
  constexpr char kAgain[] = "\nalready ending: the couch goes back first (Ctrl-\\ quits at once)\n";
  const ssize_t written = again ? ::write(STDERR_FILENO, kAgain, sizeof kAgain - 1)
                                : ::write(STDERR_FILENO, kFirst, sizeof kFirst - 1);
  (void)written;
}

// Ctrl-C and SIGTERM set g_qa_interrupted while this lives (the earlier handlers back after).
class QaInterruptHandler {
 public:
  QaInterruptHandler() {
    struct sigaction action {};
    action.sa_handler = on_qa_interrupt;
    action.sa_flags = SA_RESTART;  // any thread may take it: its blocking calls go on
    sigaction(SIGINT, &action, &old_int_);
    sigaction(SIGTERM, &action, &old_term_);
  }
  ~QaInterruptHandler() {
    sigaction(SIGINT, &old_int_, nullptr);
    sigaction(SIGTERM, &old_term_, nullptr);
  }
  QaInterruptHandler(const QaInterruptHandler&) = delete;
  QaInterruptHandler& operator=(const QaInterruptHandler&) = delete;

 private:
  struct sigaction old_int_ {
  }, old_term_{};
};

void print_line(const std::string& line) {
  std::printf("%s\n", line.c_str());
  std::fflush(stdout);
}

// What the commands do once their values are judged: the scene loaded, `announce` logged (its {}
// the scene's name), the QA
// run with the loop's own log lines quieted (each run says what it loads; the QA's lines are what
// to read), the report written and its files printed. Exit 1 with the failed checks' reasons.
Status run_and_report(
    const SceneOptions& scene, const std::string& out, const std::string& announce,
    const std::function<Result<qa::DailyQaReport>(const PreparedScene&, tracking::ThreadPool*)>& run_qa) {
  LFTRACK_RETURN_IF_ERROR(qa::check_report_folder(out));
  tracking::ThreadPool pool(scene.threads);
  auto prepared = load_prepared_scene(scene, &pool);
  if (!prepared.ok()) return prepared.status();
  if (!announce.empty()) spdlog::info("{}", fmt::format(fmt::runtime(announce), prepared->scene.name));
  const spdlog::level::level_enum level = spdlog::get_level();
  if (level == spdlog::level::info) spdlog::set_level(spdlog::level::warn);
  auto report = run_qa(*prepared, &pool);
  spdlog::set_level(level);
  if (!report.ok()) return report.status();
  auto written = qa::write_daily_qa_report(*report, out);
  if (!written.ok()) return written.status().with_context("the QA ran, but its report");
  for (const std::string& n : report->not_checked) std::printf("not checked: %s\n", n.c_str());
  const bool e2e = report->kind == "e2e";
  if (report->kind == "daily" && report->passed() && !report->standard)
    std::printf(
        "not the standard QA (looser settings, or shifts under half of TG-135's): lftrack run does not "
        "count it\n");
  std::printf("%s QA %s: %s, %s\n", e2e ? "end-to-end" : report->kind.c_str(),
              report->passed() ? "PASSED" : "FAILED", written->html.c_str(), written->json.c_str());
  if (report->passed()) return {};
  if (e2e) return failed_precondition("end-to-end QA failed: " + report->checks.front().why);
  std::string why;
  for (const qa::QaCheck& c : report->checks)
    if (!c.passed) why += "\n  " + c.name + ": " + c.why;
  return failed_precondition(report->kind + " QA failed:" + why);
}

// A folder of today's detector frames named by `flag`, checked before the scene is loaded (empty:
// none given).
Status check_frames_folder(const std::string& flag, const std::string& dir) {
  std::error_code ec;
  if (dir.empty() || std::filesystem::is_directory(dir, ec)) return {};
  return invalid_argument(flag + " " + dir +
                          ": no such folder (it holds NAME/dark and NAME/flood for each detector NAME)");
}

// Today's frames of every detector of `scene` from DIR/NAME/dark and DIR/NAME/flood. A detector
// whose folders cannot be read gets the reason (its check fails with it); the others are judged.
std::vector<qa::DetectorFrames> read_detector_frames(const Scene& scene, const std::string& dir,
                                                     int min_frames) {
  std::vector<qa::DetectorFrames> all;
  std::uint64_t bytes = 0;  // of every detector's frames, all held at once
  for (const DetectorSpec& d : scene.detectors) {
    qa::DetectorFrames f;
    FrameSize size;
    size.bytes = bytes;
    for (const bool flood : {false, true}) {
      const char* what = flood ? "flood" : "dark";
      const std::string folder = (std::filesystem::path(dir) / d.view.name / what).string();
      auto files = list_frame_folder(folder, what);
      if (!files.ok()) {
        f.unreadable = files.status().message();
        break;
      }
      if (int(files->size()) < min_frames) {
        f.unreadable = fmt::format("{} holds {} frame{}; at least {} (--min-frames)", folder, files->size(),
                                   files->size() == 1 ? "" : "s", min_frames);
        break;
      }
      auto frames = read_frame_files(*files, what, &size);
      if (!frames.ok()) {
        f.unreadable = frames.status().message();
        break;
      }
      (flood ? f.flood : f.dark) = std::move(frames).value();
    }
    if (f.unreadable.empty()) {
      bytes = size.bytes;
    } else {
      f.dark.clear();
      f.flood.clear();
    }
    all.push_back(std::move(f));
  }
  return all;
}

struct QaDailyOptions {
  SceneOptions scene;
  std::string lf_dir;
  std::string out = qa::kDefaultQaFolder;
  double tolerance_mm = qa::kStandardToleranceMm, tolerance_deg = qa::kStandardToleranceDeg;
  int latency_cycles = qa::kStandardLatencyCycles;
  double latency_ms = 0;
  std::string detector_frames;
};

Status run_qa_daily(const QaDailyOptions& o) {
  // Values first: nothing is loaded for a QA that could not be judged.
  if (!(std::isfinite(o.tolerance_mm) && o.tolerance_mm > 0 && o.tolerance_mm <= 10))
    return invalid_argument("--tolerance-mm must be above 0 and at most 10 mm");
  if (!(std::isfinite(o.tolerance_deg) && o.tolerance_deg > 0 && o.tolerance_deg <= 5))
    return invalid_argument("--tolerance-deg must be above 0 and at most 5 degrees");
  if (!(std::isfinite(o.latency_ms) && o.latency_ms >= 0 && o.latency_ms <= 10000))
    return invalid_argument("--latency-ms must be from 0 (the scene's period) to 10000 ms");
  if (o.latency_cycles > 0 && o.latency_cycles < 20)
    return invalid_argument("--latency-cycles must be 0 (not run: the QA fails) or at least 20");
  qa::DailyQaOptions options;
  options.tolerance_mm = o.tolerance_mm;
  options.tolerance_deg = o.tolerance_deg;
  options.latency_cycles = o.latency_cycles;
  options.latency_tolerance_ms = o.latency_ms;
  options.light_field_dir = o.lf_dir;
  options.progress = print_line;
  options.interrupted = &g_qa_interrupted;
  LFTRACK_RETURN_IF_ERROR(check_frames_folder("--detector-frames", o.detector_frames));
  return run_and_report(
      o.scene, o.out,
      fmt::format("daily QA of {{}}: tolerance {} mm, {} deg", o.tolerance_mm, o.tolerance_deg),
      [&](const PreparedScene& p, tracking::ThreadPool* pool) {
        if (!o.detector_frames.empty())
          options.detectors.frames =
              read_detector_frames(p.scene, o.detector_frames, options.detectors.tolerances.min_frames);
        // Around the QA alone: a Ctrl-C while the scene loads ends the program, with no report.
        const QaInterruptHandler interrupts;
        return qa::run_daily_qa(p, options, pool);
      });
}

struct QaE2eOptions {
  SceneOptions scene;
  std::string lf_dir;
  std::string out = qa::kDefaultQaFolder;
  double tolerance_mm = 1.0;
  int cycles = 300;
  std::vector<double> marker_mm{0, 0, 20};
};

Status run_qa_e2e(const QaE2eOptions& o) {
  if (!(std::isfinite(o.tolerance_mm) && o.tolerance_mm > 0 && o.tolerance_mm <= 10))
    return invalid_argument("--tolerance-mm must be above 0 and at most 10 mm");
  if (o.marker_mm.size() != 3)
    return invalid_argument("--marker-mm takes three numbers (x y z, room frame, mm)");
  qa::EndToEndOptions options;
  options.cycles = o.cycles;
  options.tolerance_mm = o.tolerance_mm;
  options.marker_offset_room_mm = Eigen::Vector3d(o.marker_mm[0], o.marker_mm[1], o.marker_mm[2]);
  if (!options.marker_offset_room_mm.allFinite() || options.marker_offset_room_mm.norm() > 200)
    return invalid_argument("--marker-mm must be finite and within 200 mm of the registration origin");
  options.light_field_dir = o.lf_dir;
  options.progress = print_line;
  return run_and_report(o.scene, o.out, "", [&](const PreparedScene& p, tracking::ThreadPool* pool) {
    return qa::run_end_to_end_qa(p, options, pool);
  });
}

struct QaDetectorOptions {
  SceneOptions scene;
  std::string frames;
  std::string out = qa::kDefaultQaFolder;
  calib::DetectorQaTolerances tolerances;
  double dark_drift_pct = 100 * calib::DetectorQaTolerances{}.max_dark_drift_fraction;
  double nonuniformity_pct = 100 * calib::DetectorQaTolerances{}.max_nonuniformity;
  double new_defects_pct = 100 * calib::DetectorQaTolerances{}.max_new_defect_fraction;
};

Status run_qa_detector(const QaDetectorOptions& o) {
  // In the options' own units first (the library's ranges are fractions).
  if (!(std::isfinite(o.dark_drift_pct) && o.dark_drift_pct > 0 && o.dark_drift_pct <= 10))
    return invalid_argument("--max-dark-drift must be above 0 and at most 10 (% of the open field)");
  if (!(std::isfinite(o.nonuniformity_pct) && o.nonuniformity_pct > 0 && o.nonuniformity_pct <= 50))
    return invalid_argument("--max-nonuniformity must be above 0 and at most 50 (%)");
  if (!(std::isfinite(o.new_defects_pct) && o.new_defects_pct >= 0 && o.new_defects_pct <= 10))
    return invalid_argument("--max-new-defects must be from 0 to 10 (% of the pixels)");
  if (!(std::isfinite(o.tolerances.max_noise_ratio) && o.tolerances.max_noise_ratio > 1 &&
        o.tolerances.max_noise_ratio <= 10))
    return invalid_argument("--max-noise-ratio must be above 1 and at most 10");
  if (o.tolerances.min_frames < calib::kMinQaFrames || o.tolerances.min_frames > calib::kMaxQaFrames)
    return invalid_argument(
        fmt::format("--min-frames must be {} to {}", calib::kMinQaFrames, calib::kMaxQaFrames));
  qa::DetectorQaOptions options;
  options.tolerances = o.tolerances;
  options.tolerances.max_dark_drift_fraction = o.dark_drift_pct / 100;
  options.tolerances.max_nonuniformity = o.nonuniformity_pct / 100;
  options.tolerances.max_new_defect_fraction = o.new_defects_pct / 100;
  LFTRACK_RETURN_IF_ERROR(calib::check_detector_qa_tolerances(options.tolerances));
  LFTRACK_RETURN_IF_ERROR(check_frames_folder("--frames", o.frames));
  return run_and_report(o.scene, o.out, "", [&](const PreparedScene& p, tracking::ThreadPool*) {
    if (!o.frames.empty())
      options.frames = read_detector_frames(p.scene, o.frames, options.tolerances.min_frames);
    return qa::run_detector_qa(p, options, print_line);
  });
}

}  // namespace

Command add_qa_detector_command(CLI::App* parent) {
  auto* app = parent->add_subcommand(
      "detector",
      "The detectors' image quality against their calibration (dark drift, noise, flat-field uniformity, new "
      "defects), on any room: today's frames from --frames DIR (DIR/NAME/dark, DIR/NAME/flood), or a "
      "simulated "
      "detector's own; a dated report (not a daily QA)");
  auto o = std::make_shared<QaDetectorOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--frames", o->frames,
                  "Folder of today's frames: NAME/dark and NAME/flood for each detector NAME (as calibrate "
                  "detector reads them); needed for detectors that are devices");
  app->add_option("--out", o->out, "Folder of the QA reports (never replaced)")->capture_default_str();
  app->add_option("--max-dark-drift", o->dark_drift_pct, "Dark level drift, % of the open field, (0, 10]")
      ->capture_default_str();
  app->add_option("--max-noise-ratio", o->tolerances.max_noise_ratio,
                  "Temporal noise / the calibration's, (1, 10]")
      ->capture_default_str();
  app->add_option("--max-nonuniformity", o->nonuniformity_pct,
                  "Flat-field non-uniformity over blocks, %, (0, 50]")
      ->capture_default_str();
  app->add_option("--max-new-defects", o->new_defects_pct,
                  "Defects not in the calibration's map, % of the pixels, [0, 10]")
      ->capture_default_str();
  app->add_option("--min-frames", o->tolerances.min_frames,
                  "Dark and flood frames each, at least (8 to 1000)")
      ->capture_default_str();
  return [o] { return run_qa_detector(*o); };
}

Command add_qa_e2e_command(CLI::App* parent) {
  auto* app = parent->add_subcommand("e2e",
                                     "The hidden-target end-to-end test (AAPM TG-135, MPPG 9.a: within 1.0 "
                                     "mm): the phantom tracked with the "
                                     "scene's motion, a marker the registration never sees followed through "
                                     "the simulator's truth; a dated report");
  auto o = std::make_shared<QaE2eOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--lf-dir", o->lf_dir, "Light-field folder (default out/lightfields/<scene>)");
  app->add_option("--out", o->out, "Folder of the QA reports (never replaced)")->capture_default_str();
  app->add_option("--tolerance-mm", o->tolerance_mm, "The hidden marker's error, p95 of beam-on cycles (mm)")
      ->capture_default_str();
  app->add_option("--cycles", o->cycles, "Cycles tracked (simulated clock)")
      ->capture_default_str()
      ->check(CLI::Range(100, 100000));
  app->add_option("--marker-mm", o->marker_mm,
                  "The hidden marker: x y z from the registration origin (room, mm)")
      ->expected(3);
  return [o] { return run_qa_e2e(*o); };
}

Command add_qa_daily_command(CLI::App* parent) {
  auto* app = parent->add_subcommand(
      "daily",
      "The daily QA on the room's phantom (AAPM TG-135): the offset test, the detectors' image quality, the "
      "beam-permit path, the latency chain and the control socket, each against its tolerance; a dated "
      "report "
      "(JSON, HTML) in --out");
  auto o = std::make_shared<QaDailyOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("--lf-dir", o->lf_dir, "Light-field folder (default out/lightfields/<scene>)");
  app->add_option("--out", o->out, "Folder of the QA reports (never replaced; `lftrack run` looks here)")
      ->capture_default_str();
  app->add_option("--tolerance-mm", o->tolerance_mm, "Offset test: registration and couch, per shift (mm)")
      ->capture_default_str();
  app->add_option("--tolerance-deg", o->tolerance_deg, "Offset test: largest rotation (degrees)")
      ->capture_default_str();
  app->add_option("--latency-cycles", o->latency_cycles,
                  "Real-clock cycles for the latency chain (0: not run, fails)")
      ->capture_default_str()
      ->check(CLI::Range(0, 100000));
  app->add_option("--latency-ms", o->latency_ms,
                  "Exposure to acknowledgement p99 tolerance (ms; 0: the scene's period)")
      ->capture_default_str();
  app->add_option("--detector-frames", o->detector_frames,
                  "Folder of today's detector frames, NAME/dark and NAME/flood per detector (as qa detector "
                  "--frames); needed where the detectors are devices");
  return [o] { return run_qa_daily(*o); };
}

}  // namespace lftrack::cli
