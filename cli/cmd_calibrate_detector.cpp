// `lftrack calibrate detector --dark DIR --flood DIR [--out FILE]`: a detector's offset, gain and
// defect maps from its own dark and flood frames (calib/detector_calibration.hpp); the file
// (host/detector_calibration_file.hpp) is what a scene names as detectors[i].calibration.
//
// Each folder holds only frames: 16-bit greyscale .tif/.tiff/.png files of one size, used in file
// name order (names starting with '.' are skipped). Anything else in it (a notes file, a folder,
// an 8-bit image) is refused with its name, so a mixed-up folder is not calibrated from. Every
// refusal happens before anything is written; the default output is never replaced.

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "cli_commands.hpp"
#include "frame_folders.hpp"
#include "lftrack/session/detector_calibration_file.hpp"

namespace lftrack::cli {

using session::is_detector_name;
using session::load_detector_calibration;
using session::write_detector_calibration;
namespace {

namespace fs = std::filesystem;

struct DetectorOptions {
  std::string dark, flood, out, detector;
  bool overwrite = false, json = false;
  int min_frames = 8;
  calib::DetectorCalibrationOptions rule;
};

Status check_detector_name(const std::string& name) {
  if (name.empty()) return {};
  if (!is_detector_name(name))
    return invalid_argument("--detector '" + name +
                            "': a detector name is 1 to 64 letters, digits, '_', '-' or '.' (not first)");
  return {};
}

std::string saturation_text(const calib::DetectorCalibration& c) {
  if (c.saturation_source == "option") return "from --saturation";
  if (c.saturation_source == "bits") return "2^" + std::to_string(c.rule.bits) + " - 1, from --bits";
  return "inferred: the largest raw value fits that full scale; give --bits or --saturation to state it";
}

Status run(const DetectorOptions& o) {
  calib::DetectorCalibrationOptions rule = o.rule;
  rule.min_dark_frames = rule.min_flood_frames = o.min_frames;
  LFTRACK_RETURN_IF_ERROR(calib::check_detector_calibration_options(rule));
  LFTRACK_RETURN_IF_ERROR(check_detector_name(o.detector));
  const fs::path out =
      o.out.empty() ? fs::path("out/calibration") / ("detector-" + (o.detector.empty() ? "detector" : o.detector) + ".tif")
                    : fs::path(o.out);
  std::error_code ec;
  if (!out.has_filename())
    return invalid_argument("--out " + out.string() + " names a folder (it ends in '/'); name the calibration file");
  if (fs::is_directory(out, ec))
    return invalid_argument("--out " + out.string() + " is a directory; name the calibration file");
  const fs::file_status existing = fs::symlink_status(out, ec);
  if (fs::exists(existing)) {
    if (!o.overwrite) return failed_precondition(out.string() + " exists; give --overwrite to replace it");
    if (!fs::is_regular_file(existing))
      return failed_precondition(out.string() + " is not a regular file (a link?); not replaced");
    // --overwrite replaces an earlier calibration, never another file (a frame, a scene) that an
    // --out typo names.
    if (auto earlier = load_detector_calibration(out); !earlier.ok())
      return failed_precondition(out.string() + " is not a detector calibration (" + earlier.status().message() +
                                 "); --overwrite replaces only a calibration file; remove it yourself if it is yours");
  }
  auto dark_files = list_frame_folder(o.dark, "dark");
  if (!dark_files.ok()) return dark_files.status();
  auto flood_files = list_frame_folder(o.flood, "flood");
  if (!flood_files.ok()) return flood_files.status();
  if (int(dark_files->size()) < rule.min_dark_frames || int(flood_files->size()) < rule.min_flood_frames)
    return invalid_argument("too few frames: " + std::to_string(dark_files->size()) + " dark in " + o.dark + ", " +
                            std::to_string(flood_files->size()) + " flood in " + o.flood + " (at least " +
                            std::to_string(o.min_frames) + " of each; --min-frames)");
  FrameSize size;
  auto dark = read_frame_files(*dark_files, "dark", &size);
  if (!dark.ok()) return dark.status();
  auto flood = read_frame_files(*flood_files, "flood", &size);
  if (!flood.ok()) return flood.status();
  spdlog::info("{} dark and {} flood frames of {} x {} pixels", dark->size(), flood->size(), size.cols, size.rows);
  for (const fs::path& f : *dark_files) rule.dark_names.push_back(f.string());
  for (const fs::path& f : *flood_files) rule.flood_names.push_back(f.string());
  auto calibration = calib::calibrate_detector(*dark, *flood, rule);
  if (!calibration.ok()) return calibration.status();
  calibration->detector = o.detector;
  if (out.has_parent_path() && !fs::exists(out.parent_path(), ec)) {
    fs::create_directories(out.parent_path(), ec);
    if (ec) return io_error("cannot create the folder " + out.parent_path().string() + ": " + ec.message());
  }
  LFTRACK_RETURN_IF_ERROR(write_detector_calibration(out, *calibration, o.overwrite));
  // What was written, as the loop will read it.
  auto written = load_detector_calibration(out);
  if (!written.ok()) return written.status().with_context("the file just written does not load back");
  const calib::DetectorCalibration& c = *written;
  const double pixels = double(c.rows) * double(c.cols);
  if (o.json) {
    nlohmann::json j = {{"file", out.string()},
                        {"detector", c.detector},
                        {"rows", c.rows},
                        {"cols", c.cols},
                        {"dark_frames", c.dark_frames},
                        {"flood_frames", c.flood_frames},
                        {"offset_median_counts", c.offset_median_counts},
                        {"noise_median_counts", c.noise_median_counts},
                        {"open_field_counts", c.open_field_counts},
                        {"saturation_counts", c.saturation_counts},
                        {"saturation_source", c.saturation_source},
                        {"defects", c.defects},
                        {"defect_rule", calib::describe_defect_rule(c.rule)},
                        {"content_hash", c.content_hash},
                        {"created", c.created}};
    for (int r = 0; r < calib::kDefectRules; ++r)
      j["defects_by_rule"][calib::defect_rule_name(r)] = c.defects_by_rule[std::size_t(r)];
    std::printf("%s\n", j.dump(2).c_str());
    return {};
  }
  std::printf("detector %s: %d x %d pixels from %d dark and %d flood frames\n",
              c.detector.empty() ? "(unnamed)" : c.detector.c_str(), c.cols, c.rows, c.dark_frames, c.flood_frames);
  std::printf("offset median %.1f counts, temporal noise median %.2f counts, open field %.1f counts (flood - dark, "
              "median over good pixels)\n",
              c.offset_median_counts, c.noise_median_counts, c.open_field_counts);
  std::printf("saturation %d counts (%s)\n", c.saturation_counts, saturation_text(c).c_str());
  std::printf("defective pixels masked: %lld (%.3f %%); by rule (a pixel counts under each it breaks):",
              static_cast<long long>(c.defects), 100.0 * double(c.defects) / pixels);
  for (int r = 0; r < calib::kDefectRules; ++r)
    std::printf("%s %s %lld", r ? "," : "", calib::defect_rule_name(r),
                static_cast<long long>(c.defects_by_rule[std::size_t(r)]));
  std::printf("\nrule: %s\n", calib::describe_defect_rule(c.rule).c_str());
  std::printf("written: %s (hash %s); a scene names it as detectors[].calibration\n", out.string().c_str(),
              c.content_hash.c_str());
  return {};
}

}  // namespace

Command add_calibrate_detector_command(CLI::App* parent) {
  auto o = std::make_shared<DetectorOptions>();
  CLI::App* app = parent->add_subcommand(
      "detector", "A detector's offset, gain and defect maps from its dark and flood frames");
  app->add_option("--dark", o->dark, "Folder of dark frames (no beam): only 16-bit .tif/.tiff/.png, one size")
      ->required();
  app->add_option("--flood", o->flood, "Folder of flood frames (open beam, nothing in it), as --dark")->required();
  app->add_option("--out", o->out,
                  "The calibration file (default out/calibration/detector-NAME.tif); never replaced without "
                  "--overwrite");
  app->add_option("--detector", o->detector, "The scene's name of the detector (checked when a scene uses the file)");
  app->add_flag("--overwrite", o->overwrite, "Replace an existing --out file");
  app->add_flag("--json", o->json, "Print the summary as JSON");
  // Every number is checked here: a value out of range is a usage error (exit 2). The library checks
  // them again for its other callers (check_detector_calibration_options).
  app->add_option("--bits", o->rule.bits,
                  "Bit depth 8..16: saturation at 2^bits - 1 (default: the smallest of 8, 10, 12, 14, 16 bits that "
                  "holds every raw value seen)")
      ->check(CLI::Range(8, 16));
  app->add_option("--saturation", o->rule.saturation_counts,
                  "Saturation level in counts, 1..65535 (overrides --bits)")
      ->check(CLI::Range(1, 65535));
  app->add_option("--min-frames", o->min_frames,
                  "At least this many dark and this many flood frames, 2..100000 (a noise estimate needs 2)")
      ->check(CLI::Range(2, 100000))
      ->capture_default_str();
  app->add_option("--dark-sd", o->rule.dark_sd, "Defect: dark level beyond this many robust SDs of the median (1..1000)")
      ->check(finite_in(1, 1000))
      ->capture_default_str();
  app->add_option("--noise-sd", o->rule.noise_sd,
                  "Defect: temporal noise beyond this many robust SDs above the median (1..1000)")
      ->check(finite_in(1, 1000))
      ->capture_default_str();
  app->add_option("--gain-low", o->rule.gain_low, "Defect: gain below this fraction of the median, in [0, 1)")
      ->check(finite_in(0, 1, false, true))
      ->capture_default_str();
  app->add_option("--gain-high", o->rule.gain_high, "Defect: gain above this multiple of the median, in (1, 100]")
      ->check(finite_in(1, 100, true))
      ->capture_default_str();
  app->add_option("--line-low", o->rule.line_low, "Defective line: median gain below this, in [0, 1)")
      ->check(finite_in(0, 1, false, true))
      ->capture_default_str();
  app->add_option("--line-high", o->rule.line_high, "Defective line: median gain above this, in (1, 100]")
      ->check(finite_in(1, 100, true))
      ->capture_default_str();
  app->add_option("--max-saturated", o->rule.max_saturated_fraction,
                  "Refuse a flood with more than this fraction of its values saturated, in [0, 1]")
      ->check(finite_in(0, 1))
      ->capture_default_str();
  return [o] { return run(*o); };
}

}  // namespace lftrack::cli
