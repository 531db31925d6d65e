#include "lftrack/session/preflight.hpp"

#include <chrono>
#include <cmath>
#include <sstream>
#include <thread>

#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/loop/cycle_schedule.hpp"
#include "lftrack/session/actuator_lock.hpp"
#include "lftrack/session/detector_calibration_file.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "session_parts.hpp"

namespace lftrack::session {

using loop::monotonic_now_ns;
using loop::RealtimeReport;

namespace {

using drivers::DeviceStatus;

void check_realtime(const PreparedScene& p, const Result<RealtimeReport>& rt, bool waived, PreflightReport* r) {
  const std::string what = "real-time set-up";
  if (!rt.ok()) return r->add(what, CheckResult::kFail, rt.status().message());
  if (waived) return r->add(what, CheckResult::kWarn, "waived by --rt ignore: " + rt->summary());
  if (!p.scene.loop.realtime.enforce)
    return r->add(
        what, CheckResult::kFail,
        "the scene's loop.realtime.mode is ignore: a treatment needs enforce (priority and cpus), or "
        "--rt ignore to waive it knowingly");
  r->add(what, CheckResult::kPass, rt->summary());
}

void check_light_fields(const PreparedScene& p, const LoopSessionOptions& o, PreflightReport* r) {
  const std::filesystem::path dir = o.light_field_dir.empty() ? default_light_field_dir(p.scene) : o.light_field_dir;
  if (p.scene.renderer == "lightfield") {
    auto fields = load_light_fields(p, dir);
    r->add("light fields (tracking) in " + dir.string(),
           fields.ok() ? CheckResult::kPass : CheckResult::kFail,
           fields.ok() ? "fresh for this CT and geometry"
                       : fields.status().message() + "; build them first: lftrack precompute --scene " +
                             p.scene.source + " -o " + dir.string());
  }
}

// Detector `d` answered as `who`: what the scene expects of it is its frames.id where it names
// one, else, for a camera that names itself as one of the simulator's served twins, this
// detector's twin (empty: nothing to check against).
std::string expected_id(const DetectorSpec& d, const drivers::DetectorIdentity& who) {
  if (!d.frames.id.empty()) return d.frames.id;
  return who.id.rfind(served_twin_id(""), 0) == 0 ? served_twin_id(d.view.name) : std::string();
}

// Opens and closes the detectors; each must answer as itself (a swapped pair of cables or
// addresses is found here, not by a failed alignment). Sets (*twins)[i] when detector i answered
// as the simulator's served twin of itself.
void check_detectors(const PreparedScene& p, const LoopSessionOptions& o, PreflightReport* r, std::vector<bool>* twins) {
  twins->assign(p.scene.detectors.size(), false);
  std::string what = "detectors";
  for (const DetectorSpec& d : p.scene.detectors) what += " " + d.view.name;
  if (o.replay_sequence.empty() && frames_are_simulated(p.scene)) {
    // Without a simulator the item "simulated detectors" has failed already (check_simulated_room).
    if (o.simulator != nullptr) r->add(what, CheckResult::kPass, "simulated (no device to open)");
    return;
  }
  Result<drivers::FrameSourceSpec> spec = invalid_argument("no spec");
  if (!o.replay_sequence.empty()) {
    drivers::ReplaySourceSpec replay;
    replay.sequence = o.replay_sequence;
    for (const DetectorSpec& d : p.scene.detectors) replay.detectors.push_back({d.view.name, d.view.rows, d.view.cols});
    spec = drivers::FrameSourceSpec(std::move(replay));
  } else {
    spec = device_frame_source_spec(p.scene);
  }
  what += " (" + describe_frames(p.scene.detectors[0].frames) + (p.scene.detectors.size() > 1 ? ", ..." : "") + ")";
  if (!spec.ok()) return r->add(what, CheckResult::kFail, spec.status().message());
  auto source = drivers::make_frame_source(std::move(spec).value());
  if (!source.ok()) return r->add(what, CheckResult::kFail, source.status().message());
  drivers::FramePair pair;
  const Status opened = (*source)->open(&pair);
  std::vector<drivers::DetectorIdentity> who(p.scene.detectors.size());
  if (opened.ok())
    for (std::size_t i = 0; i < who.size(); ++i) who[i] = (*source)->identity(i);
  (*source)->close();
  if (!opened.ok()) return r->add(what, CheckResult::kFail, opened.message());
  CheckResult result = CheckResult::kPass;
  std::ostringstream found;
  for (std::size_t i = 0; i < pair.frames.size(); ++i) {
    const DetectorSpec& d = p.scene.detectors[i];
    found << (i ? "; " : "") << d.view.name;
    if (!who[i].address.empty()) found << " at " << who[i].address;
    if (!who[i].id.empty()) found << " answered as " << who[i].id;
    const std::string expected = expected_id(d, who[i]);
    if (!expected.empty() && who[i].id != expected) {
      found << ", not " << expected;
      result = CheckResult::kFail;
    } else if (expected.empty() && !who[i].id.empty()) {
      found << " (unchecked: the scene names no frames.id)";
      if (result == CheckResult::kPass) result = CheckResult::kWarn;
    }
    if (!who[i].clock.empty()) found << ", timed by " << who[i].clock;
    if (who[i].clock_fell_back) {
      found << " (its pairs are timed by arrival: the latency chain's first link then lacks the panel's "
               "read-out)";
      if (result == CheckResult::kPass) result = CheckResult::kWarn;
    }
    (*twins)[i] = !expected.empty() && who[i].id == expected && expected == served_twin_id(d.view.name);
    found << ", " << pair.frames[i].pixels.rows() << " x " << pair.frames[i].pixels.cols();
  }
  r->add(what, result,
         "opened and closed: " + found.str() +
             (result == CheckResult::kFail ? ": each detector must answer as itself (cables or addresses "
                                             "swapped? frames.camera says where each "
                                             "is reached, frames.id what it must answer)"
                                           : ""));
}

void check_detector_calibrations(const PreparedScene& p, const LoopSessionOptions& o, const std::vector<bool>& twins,
                                 PreflightReport* r) {
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    const DetectorSpec& d = p.scene.detectors[i];
    const std::string what = "detector calibration of " + d.view.name;
    const bool device = o.replay_sequence.empty() && frames_from_device(d.frames);
    if (d.simulator_calibration && device && !twins[i]) {
      r->add(what, CheckResult::kFail,
             "calibration: simulator on a device detector (" + describe_frames(d.frames) +
                 ") that did not answer as the simulator's served twin of " + d.view.name + " (" +
                 served_twin_id(d.view.name) +
                 ", lftrack serve detectors): the simulator's detector model would correct a real panel's "
                 "frames; name "
                 "its detector calibration as detectors[].calibration (lftrack calibrate detector --dark DIR "
                 "--flood DIR)");
      continue;
    }
    if (d.simulator_calibration) {
      r->add(what, CheckResult::kWarn,
             device
                 ? "calibration: simulator: " + d.view.name + " answered as " + served_twin_id(d.view.name) +
                       ", the simulator's served twin (lftrack serve detectors), whose frames its detector "
                       "model "
                       "corrects"
                 : "calibration: simulator: the simulator's detector model corrects these frames (right only "
                   "for "
                   "frames the simulator made)");
      continue;
    }
    if (d.calibration_file.empty()) {
      if (device)
        r->add(what, CheckResult::kFail,
               "none named (detectors[].calibration): make one with lftrack calibrate detector --dark DIR "
               "--flood DIR");
      else
        r->add(what, CheckResult::kWarn,
               "none named: the simulator's detector model corrects these frames (right only for frames it "
               "made)");
      continue;
    }
    auto calibration = load_detector_calibration(d.calibration_file);
    if (!calibration.ok()) {
      r->add(what, CheckResult::kFail, calibration.status().message());
      continue;
    }
    if (calibration->rows != d.view.rows || calibration->cols != d.view.cols) {
      r->add(what, CheckResult::kFail,
             d.calibration_file + " is for " + std::to_string(calibration->rows) + " x " +
                 std::to_string(calibration->cols) + " pixels; " + d.view.name + " has " +
                 std::to_string(d.view.rows) + " x " + std::to_string(d.view.cols));
      continue;
    }
    if (!calibration->detector.empty() && calibration->detector != d.view.name) {
      r->add(what, CheckResult::kFail,
             d.calibration_file + " was made for detector '" + calibration->detector + "', not '" +
                 d.view.name + "'");
      continue;
    }
    r->add(what, CheckResult::kPass, d.calibration_file + " (hash " + calibration->content_hash + ")");
  }
}

void check_actuator(const PreparedScene& p, const LoopSessionOptions& o, PreflightReport* r) {
  const ActuatorSpec& a = p.scene.actuator;
  const std::string what = "actuator (" + describe_actuator(a) + ")";
  if (!o.replay_sequence.empty())
    return r->add(what, CheckResult::kPass, "replay: the recorded read-backs, if any");
  if (!actuator_moves(p.scene))
    return r->add(what, CheckResult::kWarn, "none: the loop tracks and reports, nothing moves");
  if (actuator_is_virtual(p.scene) && o.simulator == nullptr)
    return r->add(what, CheckResult::kFail,
                  "the simulator's couch, and this program has none (lftrack sim --room)");
  if (actuator_is_virtual(p.scene)) return r->add(what, CheckResult::kPass, "the simulator's couch");
  auto spec = device_actuator_spec(p.scene);
  if (!spec.ok()) return r->add(what, CheckResult::kFail, spec.status().message());
  // The check opens the couch and tells it to hold: never under another program driving it (a
  // treatment, a QA), which the lock names.
  auto lock = ActuatorLock::acquire(p.scene);
  if (!lock.ok()) return r->add(what, CheckResult::kFail, lock.status().message() + "; not opened");
  auto actuator = drivers::make_actuator(std::move(spec).value());
  if (!actuator.ok()) return r->add(what, CheckResult::kFail, actuator.status().message());
  if (Status s = (*actuator)->open(); !s.ok()) return r->add(what, CheckResult::kFail, s.message());
  drivers::ActuatorState state;
  DeviceStatus got = DeviceStatus::kTimeout;
  // A driver that has just connected may answer its first read-back late; a second try.
  for (int attempt = 0; attempt < 3 && got != DeviceStatus::kOk; ++attempt)
    got = (*actuator)->readback(&state, std::chrono::steady_clock::now() + std::chrono::seconds(1));
  (*actuator)->set_beam_permit(false);
  (*actuator)->hold();
  (*actuator)->close();
  if (got != DeviceStatus::kOk)
    return r->add(what, CheckResult::kFail,
                  std::string("opened, but the read-back failed: ") + to_string(got));
  std::ostringstream s;
  s.precision(3);
  s << std::fixed << "answered: position (" << state.position[0] << ", " << state.position[1] << ", "
    << state.position[2] << ") mm" << (state.moving ? ", moving" : "") << (state.fault ? ", FAULT" : "");
  r->add(what, state.fault ? CheckResult::kFail : CheckResult::kPass, s.str());
  r->actuator_position = state.position;
  if (a.calibration)
    r->add("couch calibration", CheckResult::kPass, a.calibration_file);
  else
    r->add("couch calibration", CheckResult::kWarn,
           "none named (actuator.calibration): corrections assume the couch's axes are the room's (lftrack "
           "calibrate couch)");
}

// A simulated room's own checks (its frames' light fields, a served couch's room link), by the
// simulator that would make it (room_simulator.hpp).
void check_simulated_room(const PreparedScene& p, const LoopSessionOptions& o, PreflightReport* r) {
  if (!o.replay_sequence.empty() || !frames_are_simulated(p.scene)) return;
  if (o.simulator == nullptr)
    return r->add(
        "simulated detectors", CheckResult::kFail,
        "the scene's detectors are the simulator's, and this program has none (lftrack run drives a "
        "room's own devices; lftrack sim --room runs a room with simulated detectors)");
  o.simulator->preflight(p, o, r);
}

// The optical tracker (surrogate.source igtl, a run that images on demand): connected, and
// streaming readings of the scene's device with time stamps the loop would take.
void check_surrogate(const PreparedScene& p, const LoopSessionOptions& o, PreflightReport* r) {
  const Scene& scene = p.scene;
  if (!scene.loop.imaging.model_mode() || scene.surrogate.source != "igtl" ||
      o.devices != SessionDevices::kScene || !o.replay_sequence.empty())
    return;
  const drivers::IgtlSurrogateOptions options = igtl_surrogate_options(scene);
  const std::string what = "breathing surrogate (OpenIGTLink " + options.host + ":" +
                           std::to_string(options.port) +
                           (options.device.empty() ? "" : ", device " + options.device) + ")";
  drivers::IgtlSurrogateSource tracker(options);
  if (const Status opened = tracker.open(); !opened.ok())
    return r->add(what, CheckResult::kFail, opened.message());
  const auto start = std::chrono::steady_clock::now();
  constexpr int kEnough = 10;
  while (tracker.counters().readings < kEnough &&
         std::chrono::steady_clock::now() - start < std::chrono::seconds(2))
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  drivers::SurrogateReading newest[64];
  const int n = tracker.read(monotonic_now_ns(), newest, 64);
  tracker.close();
  const drivers::IgtlSurrogateCounters c = tracker.counters();
  std::ostringstream d;
  d.precision(3);
  if (c.readings == 0 || n == 0) {
    d << "no reading in " << seconds << " s: " << c.refused_stale
      << " too old at arrival (the tracker's clock, "
      << "PTP/NTP?), " << c.refused_future << " stamped ahead of this host's clock, " << c.refused_order
      << " out of order, " << c.ignored << " other devices' or types' messages skipped"
      << (tracker.other_device_seen().empty()
              ? ""
              : " (device \"" + tracker.other_device_seen() + "\" among them)")
      << (c.several_devices ? " (several devices: name the marker's in surrogate.igtl.device)" : "") << ", "
      << c.protocol_errors << " protocol errors";
    return r->add(what, CheckResult::kFail, d.str());
  }
  d << c.readings << " readings in " << seconds << " s, the newest " << newest[n - 1].amplitude
    << " mm along surrogate.igtl.axis, " << 1e-6 * double(monotonic_now_ns() - newest[n - 1].t_ns)
    << " ms old";
  const std::int64_t refused = c.refused_stale + c.refused_future + c.refused_order;
  if (refused > 0 || c.protocol_errors > 0 || !std::isfinite(newest[n - 1].amplitude)) {
    d << "; " << refused << " refused for their time stamps, " << c.protocol_errors << " protocol errors"
      << (std::isfinite(newest[n - 1].amplitude) ? "" : "; the newest reading is not finite");
    return r->add(what, CheckResult::kWarn, d.str());
  }
  r->add(what, CheckResult::kPass, d.str());
}

}  // namespace

void PreflightReport::add(std::string what, CheckResult result, std::string detail) {
  items.push_back({std::move(what), result, std::move(detail)});
}

bool PreflightReport::passed() const {
  for (const PreflightItem& i : items)
    if (i.result == CheckResult::kFail) return false;
  return true;
}

std::string PreflightReport::checklist() const {
  std::ostringstream s;
  for (const PreflightItem& i : items)
    s << (i.result == CheckResult::kPass ? "[ ok ] " : i.result == CheckResult::kWarn ? "[warn] " : "[FAIL] ") << i.what
      << ": " << i.detail << "\n";
  return s.str();
}

std::string PreflightReport::failures() const {
  std::ostringstream s;
  for (const PreflightItem& i : items)
    if (i.result == CheckResult::kFail) s << "  " << i.what << ": " << i.detail << "\n";
  return s.str();
}

PreflightReport run_preflight(const PreparedScene& p, const LoopSessionOptions& o, const Result<RealtimeReport>& realtime,
                              bool rt_waived) {
  PreflightReport r;
  check_realtime(p, realtime, rt_waived, &r);
  r.add("view geometry", CheckResult::kPass,
        "from the scene file " + p.scene.source + " (lftrack calibrate views writes it there)");
  check_light_fields(p, o, &r);
  std::vector<bool> twins;
  check_detectors(p, o, &r, &twins);
  check_detector_calibrations(p, o, twins, &r);
  check_actuator(p, o, &r);
  // After the actuator: a served couch's room link is compared with the couch's read-back.
  check_simulated_room(p, o, &r);  // the simulated frames' light fields, the served couch's room link
  check_surrogate(p, o, &r);
  return r;
}

}  // namespace lftrack::session
