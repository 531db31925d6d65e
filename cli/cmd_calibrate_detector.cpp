// `lftrack calibrate detector --dark DIR --flood DIR [--out FILE]`: a detector's offset, gain and
// defect maps from its own dark and flood frames (calib/detector_calibration.hpp); the file
// (host/detector_calibration_file.hpp) is what a scene names as detectors[i].calibration.

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "cli_commands.hpp"
#include "lftrack/drivers/frame_files.hpp"
#include "lftrack/host/detector_calibration_file.hpp"

namespace lftrack::host::cli {
namespace {

namespace fs = std::filesystem;

struct DetectorOptions {
  std::string dark, flood, out, detector;
  bool overwrite = false, json = false;
  calib::DetectorCalibrationOptions rule;
};

constexpr std::size_t kMaxFrames = 2000;
constexpr std::uint64_t kMaxBytes = std::uint64_t(2) << 30;  // frames held in memory at once

bool is_frame_file(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext == ".tif" || ext == ".tiff" || ext == ".png";
}

// The frames of `dir` (its .tif, .tiff and .png files, in name order), all of one size: the
// first frame's, or `rows` x `cols` when given (> 0).
Result<std::vector<tracking::Image<std::uint16_t>>> read_folder(const std::string& dir, const char* what, int* rows,
                                                                int* cols) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return not_found(std::string(what) + " folder " + dir + ": no such directory");
  std::vector<fs::path> files;
  std::size_t others = 0;
  for (const fs::directory_entry& e : fs::directory_iterator(dir, ec)) {
    if (e.path().filename().string().front() == '.') continue;
    if (e.is_regular_file(ec) && is_frame_file(e.path()))
      files.push_back(e.path());
    else
      ++others;
  }
  if (ec) return io_error(std::string(what) + " folder " + dir + ": " + ec.message());
  if (files.empty())
    return invalid_argument(std::string(what) + " folder " + dir + " holds no frames (.tif, .tiff or .png files)");
  if (files.size() > kMaxFrames)
    return invalid_argument(std::string(what) + " folder " + dir + " holds " + std::to_string(files.size()) +
                            " frames; at most " + std::to_string(kMaxFrames) + " are used for a calibration");
  if (others > 0) spdlog::warn("{} folder {}: {} other entries ignored (not frame files)", what, dir, others);
  std::sort(files.begin(), files.end());
  if (*rows <= 0) LFTRACK_RETURN_IF_ERROR(drivers::frame_file_size(files[0].c_str(), rows, cols));
  if (std::uint64_t(*rows) * std::uint64_t(*cols) * 2 * files.size() > kMaxBytes)
    return invalid_argument(std::string(what) + " frames would take more than 2 GiB; use fewer frames");
  std::vector<tracking::Image<std::uint16_t>> frames;
  for (const fs::path& f : files) {
    frames.emplace_back(*rows, *cols);
    if (Status s = drivers::read_frame_file(f.c_str(), frames.back().view()); !s.ok())
      return s.with_context(std::string(what) + " frame");
  }
  return frames;
}

fs::path default_out(const DetectorOptions& o) {
  return fs::path("out/calibration") / ("detector-" + (o.detector.empty() ? std::string("detector") : o.detector) + ".tif");
}

Status run(const DetectorOptions& o) {
  LFTRACK_RETURN_IF_ERROR(calib::check_detector_calibration_options(o.rule));
  const fs::path out = o.out.empty() ? default_out(o) : fs::path(o.out);
  std::error_code ec;
  if (fs::is_directory(out, ec)) return invalid_argument("--out " + out.string() + " is a directory; name a file");
  if (fs::exists(fs::symlink_status(out, ec)) && !o.overwrite)
    return failed_precondition(out.string() + " exists; give --overwrite to replace it");
  int rows = 0, cols = 0;
  auto dark = read_folder(o.dark, "dark", &rows, &cols);
  if (!dark.ok()) return dark.status();
  auto flood = read_folder(o.flood, "flood", &rows, &cols);
  if (!flood.ok()) return flood.status();
  spdlog::info("{} dark and {} flood frames of {} x {} pixels", dark->size(), flood->size(), cols, rows);
  auto calibration = calib::calibrate_detector(*dark, *flood, o.rule);
  if (!calibration.ok()) return calibration.status();
  calibration->detector = o.detector;
  calibration->content_hash = calib::detector_calibration_hash(*calibration);
  if (!out.parent_path().empty()) fs::create_directories(out.parent_path(), ec);
  LFTRACK_RETURN_IF_ERROR(write_detector_calibration(out, *calibration, o.overwrite));
  const calib::DetectorCalibration& c = *calibration;
  double offset_sum = 0, noise_sum = 0;
  for (int r = 0; r < c.rows; ++r)
    for (int k = 0; k < c.cols; ++k) {
      offset_sum += c.offset_counts.at(r, k);
      noise_sum += c.noise_counts.at(r, k);
    }
  const double pixels = double(c.rows) * double(c.cols);
  if (o.json) {
    nlohmann::json j = {{"file", out.string()},          {"detector", c.detector},
                        {"rows", c.rows},                {"cols", c.cols},
                        {"dark_frames", c.dark_frames},  {"flood_frames", c.flood_frames},
                        {"offset_mean_counts", offset_sum / pixels}, {"noise_mean_counts", noise_sum / pixels},
                        {"open_field_counts", c.open_field_counts}, {"saturation_counts", c.saturation_counts},
                        {"defects", c.defects},          {"content_hash", c.content_hash}};
    for (int r = 0; r < calib::kDefectRules; ++r)
      j["defects_by_rule"][calib::defect_rule_name(r)] = c.defects_by_rule[std::size_t(r)];
    std::printf("%s\n", j.dump(2).c_str());
    return {};
  }
  std::printf("detector %s: %d x %d pixels from %d dark and %d flood frames\n",
              c.detector.empty() ? "(unnamed)" : c.detector.c_str(), c.cols, c.rows, c.dark_frames, c.flood_frames);
  std::printf("offset %.1f counts mean, temporal noise %.2f counts mean; open field %.1f counts; saturation %d\n",
              offset_sum / pixels, noise_sum / pixels, c.open_field_counts, c.saturation_counts);
  std::printf("defective pixels masked: %lld (%.3f %%):", static_cast<long long>(c.defects), 100.0 * double(c.defects) / pixels);
  for (int r = 0; r < calib::kDefectRules; ++r)
    std::printf(" %s %lld", calib::defect_rule_name(r), static_cast<long long>(c.defects_by_rule[std::size_t(r)]));
  std::printf("\nrule: dark level or temporal noise beyond %.0f / %.0f robust SDs, gain outside [%.2f, %.2f], "
              "saturated in a flood, lines with median gain outside [%.2f, %.2f]\n",
              c.rule.dark_sd, c.rule.noise_sd, c.rule.gain_low, c.rule.gain_high, c.rule.line_low, c.rule.line_high);
  std::printf("written: %s (hash %s); a scene names it as detectors[].calibration\n", out.string().c_str(),
              c.content_hash.c_str());
  return {};
}

}  // namespace

Command add_calibrate_detector_command(CLI::App* parent) {
  auto o = std::make_shared<DetectorOptions>();
  CLI::App* app = parent->add_subcommand(
      "detector", "A detector's offset, gain and defect maps from its dark and flood frames");
  app->add_option("--dark", o->dark, "Folder of dark frames (no beam): 16-bit .tif/.png")->required();
  app->add_option("--flood", o->flood, "Folder of flood frames (open beam, nothing in it)")->required();
  app->add_option("--out", o->out, "The calibration file (default out/calibration/detector-NAME.tif); never overwritten "
                                   "without --overwrite");
  app->add_option("--detector", o->detector, "The scene's name of the detector (checked when a scene uses the file)");
  app->add_option("--bits", o->rule.bits, "Bit depth (saturation at 2^bits - 1)")->check(CLI::Range(8, 16))->capture_default_str();
  app->add_option("--saturation", o->rule.saturation_counts, "Saturation level in counts (0: from --bits)")
      ->check(CLI::Range(0, 65535));
  app->add_option("--min-frames", o->rule.min_dark_frames, "At least this many dark (and flood) frames")
      ->check(CLI::Range(2, 100000))
      ->capture_default_str();
  app->add_option("--dark-sd", o->rule.dark_sd, "Defect: dark level beyond this many robust SDs")->capture_default_str();
  app->add_option("--noise-sd", o->rule.noise_sd, "Defect: temporal noise beyond this many robust SDs")->capture_default_str();
  app->add_flag("--overwrite", o->overwrite, "Replace an existing --out file");
  app->add_flag("--json", o->json, "Print the summary as JSON");
  return [o] {
    o->rule.min_flood_frames = o->rule.min_dark_frames;
    return run(*o);
  };
}

}  // namespace lftrack::host::cli
