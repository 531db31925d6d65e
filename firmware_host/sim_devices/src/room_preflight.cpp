// The simulated room's checks before a run (RoomSimulator::preflight, preflight.hpp): the light
// fields its frames are rendered from, and the served couch's room link that simulated
// detectors see the patient move through (written, and lately: its server running).

#include <spdlog/spdlog.h>  // fmt

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
// How far the link's couch may stand from the actuator's read-back at the checks (the couch is
// held; its read-back carries micrometres and microradians, over Modbus and CAN alike).
constexpr double kMaxCouchLinkOffsetMm = 0.1;
constexpr double kMaxCouchLinkOffsetDeg = 0.1;

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
// The command that serves the scene's actuator with a room link.
std::string serve_command(const PreparedScene& p) {
  return p.scene.actuator.type == "can" ? "lftrack serve robot --socket ... --room " + p.scene.sim.couch_link
                                        : "lftrack serve couch --modbus ... --room " + p.scene.sim.couch_link;
}

// The served couch's room link (sim.couch_link): there, written by a server that runs now, lately
// (it writes every millisecond), and showing the couch where the scene's actuator, read back just
// before (PreflightReport::actuator_position), says it stands: a link of another couch, or of
// none, would show the detectors a patient who never moves with the couch the loop commands.
void check_couch_link(const PreparedScene& p, PreflightReport* r) {
  if (!actuator_is_device(p.scene)) return;
  const std::string what = "the served couch's room link (sim.couch_link)";
  const std::string& path = p.scene.sim.couch_link;
  if (path.empty())
    return r->add(what, CheckResult::kFail,
                  "none named: simulated detectors would never see the patient move with the " +
                      p.scene.actuator.type + " actuator (lftrack serve couch|robot --room FILE)");
  auto link = sim::RoomLinkReader::open(path);
  if (!link.ok()) return r->add(what, CheckResult::kFail, link.status().message());
  sim::RoomLinkSample sample;
  if (!(*link)->read(&sample))
    return r->add(what, CheckResult::kFail, path + ": nothing written yet (" + serve_command(p) + ")");
  const std::string writer = "process " + std::to_string(sample.writer_pid);
  if (!sim::RoomLinkReader::writer_running(path))
    return r->add(what, CheckResult::kFail,
                  path + ": no process writes it now (last " + writer +
                      "): its server has ended (start it again: " + serve_command(p) + ")");
  const double age_s = double(sim::room_link_now_ns() - sample.written_ns) * 1e-9;
  if (age_s < -kMaxCouchLinkAgeS)
    return r->add(what, CheckResult::kFail,
                  path + ": its newest sample is stamped " + fmt::format("{:.3f} s", -age_s) +
                      " ahead of this host's clock (" + writer +
                      "): not a link written on this boot by a server that runs now");
  if (age_s > kMaxCouchLinkAgeS)
    return r->add(what, CheckResult::kFail,
                  path + ": last written " + fmt::format("{:.3f} s", age_s) + " ago by " + writer +
                      ", which writes every millisecond while it runs: its server is stalled (stopped or "
                      "starved); end it and start it again (" +
                      serve_command(p) + ")");
  if (r->actuator_position) {
    const tracking::Vector6d off = sample.couch_position - *r->actuator_position;
    const double off_mm = off.head<3>().norm(), off_deg = tracking::rad_to_deg(off.tail<3>().norm());
    if (!(off_mm <= kMaxCouchLinkOffsetMm && off_deg <= kMaxCouchLinkOffsetDeg))
      return r->add(what, CheckResult::kFail,
                    fmt::format("{} ({}): the link's couch stands {:.3f} mm and {:.3f} deg from where the {} "
                                "actuator answered it stands: it is another couch's link, and the detectors "
                                "would not see this couch move the patient",
                                path, writer, off_mm, off_deg, p.scene.actuator.type));
  }
  r->add(what, CheckResult::kPass,
         path + " (written by " + writer + ", " + fmt::format("{:.3f} s", age_s) + " ago" +
             (r->actuator_position ? ", where the actuator answered it stands)" : ")"));
}

}  // namespace

void room_preflight(const PreparedScene& p, const LoopSessionOptions& o, PreflightReport* r) {
  check_frame_light_fields(p, o, r);
  check_couch_link(p, r);
}

}  // namespace lftrack::sim_devices
