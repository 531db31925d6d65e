// The simulated room's checks before a run (RoomSimulator::preflight, preflight.hpp): the light
// fields its frames are rendered from, and the served couch's room link that simulated
// detectors see the patient move through (written, and lately: its server running).

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>
#include <utility>

#include "lftrack/session/preflight.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/sim/room_link.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"
#include "room_parts.hpp"

namespace lftrack::sim_devices {

using session::actuator_is_device;
using session::CheckResult;
using session::default_light_field_dir;
using session::load_light_fields;
using session::LoopSessionOptions;
using session::PreflightReport;
using session::PreparedScene;

namespace {

// How old the newest sample of a served couch's room link may be at the start-up checks: a
// thousand of its periods.
constexpr double kMaxCouchLinkAgeS = 1.0;

std::int64_t steady_now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

std::string format_seconds(double s) {
  char text[32];
  std::snprintf(text, sizeof text, "%.3f s", s);
  return text;
}

// The simulated frames' light fields (sim.renderer lightfield): fresh for the day's volumes.
void check_frame_light_fields(const PreparedScene& p, const LoopSessionOptions& o, PreflightReport* r) {
  if (p.scene.sim.renderer != "lightfield") return;
  const std::filesystem::path dir =
      o.light_field_dir.empty() ? default_light_field_dir(p.scene) : o.light_field_dir;
  const std::filesystem::path sim_dir = sim_frame_fields_dir(p, o.light_field_dir);
  const std::string build =
      "; build them first: lftrack precompute --scene " + p.scene.source + " -o " + dir.string();
  if (p.scene.sim.physics.ideal()) {
    auto fields = load_light_fields(p, sim_dir, p.world_mu.get(), &p.scene.sim.light_field);
    r->add("light fields (simulated frames) in " + sim_dir.string(),
           fields.ok() ? CheckResult::kPass : CheckResult::kFail,
           fields.ok() ? "fresh" : fields.status().message() + build);
    return;
  }
  // Fields of the day's volumes (water and bone, or attenuation): those volumes are made again
  // from the CT (the anatomy draw; seconds), and their fields loaded, not built.
  auto patient = simulated_patient_volumes(p, p.scene.sim.physics, scene_anatomy_seed(p), nullptr);
  if (!patient.ok())
    return r->add("light fields (simulated frames) in " + sim_dir.string(), CheckResult::kFail,
                  patient.status().message());
  for (const auto& [name, volume] : {std::pair{"attenuation", patient->attenuation},
                                     std::pair{"water", patient->water}, std::pair{"bone", patient->bone}}) {
    if (!volume) continue;
    auto fields = load_light_fields(p, sim_dir / name, volume.get(), &p.scene.sim.light_field);
    r->add("light fields (simulated frames, " + std::string(name) + ") in " + (sim_dir / name).string(),
           fields.ok() ? CheckResult::kPass : CheckResult::kFail,
           fields.ok() ? "fresh" : fields.status().message() + build);
  }
}

// Simulated detectors with a served couch: the patient moves only through the couch's room link.
void check_couch_link(const PreparedScene& p, PreflightReport* r) {
  if (!actuator_is_device(p.scene)) return;
  const std::string what = "the served couch's room link (sim.couch_link)";
  if (p.scene.sim.couch_link.empty())
    return r->add(what, CheckResult::kFail,
                  "none named: simulated detectors would never see the patient move with the " +
                      p.scene.actuator.type + " actuator (lftrack serve couch|robot --room FILE)");
  auto link = sim::RoomLinkReader::open(p.scene.sim.couch_link);
  if (!link.ok()) return r->add(what, CheckResult::kFail, link.status().message());
  sim::RoomLinkSample sample;
  if (!(*link)->read(&sample))
    return r->add(what, CheckResult::kFail, p.scene.sim.couch_link + ": nothing written yet");
  // A running server writes where its couch stands every millisecond: a link older than that by
  // far is one whose server has stopped (killed, or stalled), and simulated detectors reading it
  // would show a patient who never moves with the couch the loop commands.
  const double age_s = double(steady_now_ns() - sample.written_ns) * 1e-9;
  if (age_s > kMaxCouchLinkAgeS)
    return r->add(
        what, CheckResult::kFail,
        p.scene.sim.couch_link + ": last written " + format_seconds(age_s) + " ago by process " +
            std::to_string(sample.writer_pid) +
            ", which writes every millisecond while it runs: its server has stopped (start it again: "
            "lftrack serve couch|robot --room FILE)");
  r->add(what, CheckResult::kPass,
         p.scene.sim.couch_link + " (written by process " + std::to_string(sample.writer_pid) + ", " +
             format_seconds(age_s) + " ago)");
}

}  // namespace

void room_preflight(const PreparedScene& p, const LoopSessionOptions& o, PreflightReport* r) {
  check_frame_light_fields(p, o, r);
  check_couch_link(p, r);
}

}  // namespace lftrack::sim_devices
