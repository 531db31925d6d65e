// `lftrack precompute`: builds each view's light field on all cores and writes one file per view,
// named after what the field depends on (scene.hpp); a field already there is up to date and kept.
// A scene whose frames the simulator draws from light fields (detectors `frames: sim`,
// sim.renderer: lightfield) gets the simulator's fields too, in <folder>/sim-frames, so that
// `lftrack run` on it (a simulated room, the daily QA's phantom) finds everything it checks for.

#include <spdlog/spdlog.h>

#include <cstdio>
#include <filesystem>
#include <set>

#include "cli_commands.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::default_light_field_dir;
using session::frames_are_simulated;
using session::LightFieldCacheReport;
using session::load_or_build_light_fields;
using session::PreparedScene;
using sim_devices::make_scene_patient;
using sim_devices::make_sim_frame_renderer;
using sim_devices::sim_frame_fields_dir;
namespace {

struct PrecomputeOptions {
  SceneOptions scene;
  std::string out_dir;  // empty: default_light_field_dir
};

Status run(const PrecomputeOptions& o) {
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  LFTRACK_RETURN_IF_ERROR(precompute_light_fields(*prepared, o.out_dir, &pool));
  return precompute_sim_frame_fields(*prepared, o.out_dir, &pool);
}

}  // namespace

Status precompute_light_fields(const PreparedScene& p, const std::string& out_dir, tracking::ThreadPool* pool_ptr) {
  tracking::ThreadPool& pool = *pool_ptr;
  const std::filesystem::path dir =
      out_dir.empty() ? default_light_field_dir(p.scene) : std::filesystem::path(out_dir);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return io_error(dir.string() + ": cannot create folder: " + ec.message());
  const auto& spec = p.scene.light_field;
  spdlog::info("light fields {} x {} x {} x {}, {} storage{}, integrated by {}{}, {} threads", spec.resolution[0],
               spec.resolution[1], spec.resolution[2], spec.resolution[3], tracking::to_string(spec.storage),
               spec.storage == tracking::LightFieldStorage::kVq
                   ? " (" + std::to_string(spec.vq_codebook_size) + " codewords)"
                   : "",
               tracking::to_string(spec.integration),
               spec.integration == tracking::LightFieldIntegration::kSlices
                   ? fmt::format(" of {:.2f} mm", tracking::light_field_slice_step_mm(*p.mu, spec.slice_step_mm))
                   : "",
               pool.size());
  LightFieldCacheReport report;
  auto fields = load_or_build_light_fields(p, *p.mu, spec, dir, &pool, &report);
  if (!fields.ok()) return fields.status();
  if (!report.saved.ok()) return report.saved;
  for (std::size_t i = 0; i < fields->size(); ++i) {
    const auto& field = (*fields)[i];
    const auto& g = field->geometry();
    if (report.built[i])
      spdlog::info(
          "view {}: u {:.1f}..{:.1f}, v {:.1f}..{:.1f}, s {:.1f}..{:.1f}, t {:.1f}..{:.1f} mm; {:.1f} MB",
          g.view_name, g.lo[0], g.hi[0], g.lo[1], g.hi[1], g.lo[2], g.hi[2], g.lo[3], g.hi[3],
          double(field->payload_bytes()) / 1e6);
    std::printf("%s: %s\n", report.files[i].string().c_str(), report.built[i] ? "built" : "up to date");
  }
  return {};
}

Status precompute_sim_frame_fields(const PreparedScene& p, const std::string& out_dir,
                                   tracking::ThreadPool* pool) {
  if (!frames_are_simulated(p.scene) || p.scene.sim.renderer != "lightfield") return {};
  const std::filesystem::path dir = sim_frame_fields_dir(p, out_dir);
  // The fields there before, so that the line says whether any had to be built.
  auto field_files = [&] {
    std::set<std::filesystem::path> files;
    std::error_code ec;
    for (std::filesystem::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
      if (it->path().extension() == ".lf") files.insert(it->path());
    return files;
  };
  const std::set<std::filesystem::path> before = field_files();
  spdlog::info("the simulator's frame fields in {} (sim.light_field)", dir.string());
  // The realistic patient's volumes (attenuation, or water and bone) where the scene's physics is
  // not ideal, else the world's attenuation: loaded where up to date, built and saved where not,
  // as `sim` and `run` would before their first frame.
  auto patient = make_scene_patient(p, out_dir, pool);
  if (!patient.ok()) return patient.status().with_context("the simulator's frame fields");
  if (!*patient) {
    auto renderer = make_sim_frame_renderer(p, out_dir, pool);
    if (!renderer.ok()) return renderer.status();
  }
  std::size_t built = 0;
  for (const auto& f : field_files()) built += before.count(f) == 0 ? 1 : 0;
  if (built > 0)
    std::printf("%s: %zu built\n", dir.string().c_str(), built);
  else
    std::printf("%s: up to date\n", dir.string().c_str());
  return {};
}

Command add_precompute_command(CLI::App* parent) {
  auto* app =
      parent->add_subcommand("precompute",
                             "Build the scene's light fields, one file per view (those up to date are kept, "
                             "not rebuilt); with simulated "
                             "frames drawn from light fields, the simulator's too (in <folder>/sim-frames)");
  auto o = std::make_shared<PrecomputeOptions>();
  add_scene_options(app, &o->scene);
  app->add_option("-o,--out", o->out_dir,
                  "Output folder, shared by any scenes (files VIEW-KEY.lf; default: out/lightfields/<scene>)");
  return [o] { return run(*o); };
}

}  // namespace lftrack::cli
