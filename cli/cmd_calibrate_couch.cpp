// `lftrack calibrate couch`: the couch's axes and rotation centre in the room (issue 8).

#include <spdlog/spdlog.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "cli_commands.hpp"
#include "lftrack/session/calibration_files.hpp"
#include "lftrack/session/progress_bar.hpp"
#include "lftrack/sim_devices/couch_calibration_run.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::couch_calibration_yaml;
using session::load_calibration_phantom;
using session::ProgressBar;
using session::read_couch_calibration;
using session::read_couch_moves;
using sim_devices::CouchCalibrationRunOptions;
using sim_devices::run_simulated_couch_calibration;
namespace {

struct CouchOptions {
  SceneOptions scene;
  std::string moves = "builtin";
  std::string phantom = "builtin";
  std::string out;
  bool overwrite = false;
  double photons = 1e6;
  std::uint64_t seed = 1;
  bool json = false;
};

// --out: refused where it exists, unless --overwrite, and then only an earlier couch calibration
// (never a scene or another file an --out typo names). Checked before the run.
Status check_out(const CouchOptions& o) {
  if (o.out.empty()) return {};
  namespace fs = std::filesystem;
  const fs::path out(o.out);
  std::error_code ec;
  if (!out.has_filename())
    return invalid_argument("--out " + o.out + " names a folder (it ends in '/'); name the calibration file");
  const fs::file_status existing = fs::symlink_status(out, ec);
  if (!fs::exists(existing)) return {};
  if (fs::is_directory(existing))
    return invalid_argument("--out " + o.out + " is a directory; name the calibration file");
  if (!o.overwrite) return failed_precondition(o.out + " exists; give --overwrite to replace it");
  if (!fs::is_regular_file(existing))
    return failed_precondition(o.out + " is not a regular file (a link?); not replaced");
  if (auto earlier = read_couch_calibration(o.out); !earlier.ok())
    return failed_precondition(
        o.out + " is not a couch calibration (" + earlier.status().message() +
        "); --overwrite replaces only a couch calibration; remove it yourself if it is yours");
  return {};
}

Status run(const CouchOptions& o) {
  LFTRACK_RETURN_IF_ERROR(check_out(o));
  auto phantom = load_calibration_phantom(o.phantom);
  if (!phantom.ok()) return phantom.status();
  CouchCalibrationRunOptions options;
  options.phantom = *phantom;
  options.photons_per_pixel = o.photons;
  options.seed = o.seed;
  if (o.moves != "builtin") {
    auto moves = read_couch_moves(o.moves);
    if (!moves.ok()) return moves.status();
    options.moves = *moves;
  }
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  ProgressBar bar("couch moves");
  options.progress = [&](int done, int total) { bar.update(double(done) / double(total)); };
  auto run = run_simulated_couch_calibration(*prepared, options);
  (void)bar.finish();
  if (!run.ok()) return run.status();
  const calib::CouchCalibration& c = run->calibration;
  spdlog::info("couch calibration: {} moves, rms {:.4f} mm, rotation sd {:.4f} deg, centre sd {:.3f} mm",
               run->observations.size(), c.rms_mm, c.rotation_sd_deg.norm(), c.centre_sd_mm.norm());
  if (!o.out.empty()) {
    std::ofstream out(o.out);
    out << couch_calibration_yaml(
        c, run->observations.size(),
        "simulated room of scene " + prepared->scene.source + ", phantom '" + phantom->name + "'");
    if (!out) return io_error("cannot write '" + o.out + "'");
    spdlog::info("wrote {}", o.out);
  }
  nlohmann::json j;
  const Eigen::Vector3d r =
      tracking::rotation_log(c.T_room_from_couch.linear()) * (180 / 3.14159265358979323846);
  j["rotation_deg"] = {r.x(), r.y(), r.z()};
  j["centre_mm"] = {c.T_room_from_couch.translation().x(), c.T_room_from_couch.translation().y(),
                    c.T_room_from_couch.translation().z()};
  j["rms_mm"] = c.rms_mm;
  j["rotation_sd_deg"] = c.rotation_sd_deg.norm();
  j["centre_sd_mm"] = c.centre_sd_mm.norm();
  j["moves"] = run->observations.size();
  j["worst_phantom_fre_mm"] = run->worst_fre_mm;
  j["rotation_error_deg"] = run->rotation_error_deg;
  j["centre_error_mm"] = run->centre_error_mm;
  if (o.json) {
    std::printf("%s\n", j.dump(2).c_str());
  } else {
    std::printf(
        "couch axes recovered within %.4f deg, rotation centre within %.3f mm of the simulated mounting "
        "(rms %.4f mm over %zu moves)\n",
        run->rotation_error_deg, run->centre_error_mm, c.rms_mm, run->observations.size());
  }
  return {};
}

}  // namespace

Command add_calibrate_couch_command(CLI::App* parent) {
  auto o = std::make_shared<CouchOptions>();
  CLI::App* app = parent->add_subcommand(
      "couch", "The couch's axes and rotation centre in the room, from known moves (simulated room)");
  add_scene_options(app, &o->scene);
  app->add_option("--moves", o->moves, "Moves file (YAML), or 'builtin' (+-10 mm, +-2 deg per axis)")
      ->capture_default_str();
  app->add_option("--phantom", o->phantom, "Phantom on the couch (YAML), or 'builtin'")
      ->capture_default_str();
  app->add_option("--out", o->out,
                  "Write the couch calibration (YAML) here; a scene names it as actuator.calibration");
  app->add_flag("--overwrite", o->overwrite,
                "Replace an existing --out file (an earlier couch calibration only)");
  app->add_option("--photons", o->photons, "Open-field quanta per pixel of the phantom images, 0 (no noise) to 1e9")
      ->check(finite_in(0, 1e9))
      ->capture_default_str();
  app->add_option("--seed", o->seed, "Noise of the phantom images")->check(seed_value())->capture_default_str();
  app->add_flag("--json", o->json, "Print the report as JSON on stdout");
  return [o] { return run(*o); };
}

}  // namespace lftrack::cli
