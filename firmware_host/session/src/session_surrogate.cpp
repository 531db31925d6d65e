// The session's breathing surrogate and imaging dose (session_parts.hpp: make_session_surrogate).

#include <spdlog/spdlog.h>

#include <algorithm>

#include "lftrack/drivers/igtl_surrogate.hpp"
#include "lftrack/session/scene_imaging_dose.hpp"
#include "session_parts.hpp"

namespace lftrack::session {

using loop::CorrelationModelSpec;
using loop::ImagingSpec;
using loop::LoopSettings;

drivers::IgtlSurrogateOptions igtl_surrogate_options(const Scene& scene) {
  drivers::IgtlSurrogateOptions client;
  client.host = scene.surrogate.igtl_host;
  client.port = scene.surrogate.igtl_port;
  client.device = scene.surrogate.igtl_device;
  client.axis_room = scene.surrogate.igtl_axis;
  client.stale_ms = scene.loop.imaging.surrogate.stale_ms;
  return client;
}

Status check_session_surrogate(const Scene& scene, const LoopSessionOptions& o) {
  if (!scene.loop.imaging.model_mode() || !o.replay_sequence.empty()) return {};
  // A model cycle's reading is its frame: the gate's frame age applies to it, and a watch slower
  // than the gate would hold a stopped tracker as "stale frame", after counted skips.
  const double stale_ms = scene.loop.imaging.surrogate.stale_ms, frame_age_ms = scene.safety.max_frame_age_ms;
  if (stale_ms > frame_age_ms)
    return invalid_argument(scene.where("surrogate") + ": surrogate.stale_ms (" +
                            fmt::format("{:g}", stale_ms) + " ms) exceeds safety.max_frame_age_ms (" +
                            fmt::format("{:g}", frame_age_ms) +
                            " ms): between X-ray pairs the surrogate's reading is the cycle's frame; keep "
                            "stale_ms at most the frame age");
  const std::string& source = scene.surrogate.source;
  if (source == "sim" && o.devices == SessionDevices::kScene)
    return failed_precondition(scene.where("surrogate") +
                               ": surrogate.source sim is the simulated patient's chest marker, for "
                               "lftrack sim without --room; a treatment room's "
                               "surrogate is an optical tracker (surrogate.source igtl)");
  if (source == "igtl" && o.devices == SessionDevices::kSimulated && o.simulated_clock)
    return failed_precondition(
        scene.where("surrogate") +
        ": surrogate.source igtl reads a tracker's time-stamped positions on the real clock; lftrack sim "
        "--fast runs on a simulated one. Run it without --fast, or follow the simulated marker directly "
        "(surrogate.source sim)");
  return {};
}

Status make_session_surrogate(const PreparedScene& p, const LoopSessionOptions& o, LoopSession::Parts* parts,
                              LoopSettings* settings) {
  ImagingSpec& imaging = settings->loop.imaging;
  // A replay exposes nobody: no dose, and every archived pair registered.
  imaging.dose_per_pair_mGy = parts->replay_frames != nullptr ? 0.0 : imaging_dose_per_pair_mGy(p);
  if (!imaging.model_mode()) return {};
  if (parts->replay_frames != nullptr) {
    spdlog::info(
        "replay: every archived pair is registered (the scene's tracking.imaging model is for live frames; "
        "an archive recorded with it holds only the pairs taken, about a second apart)");
    imaging.mode = ImagingSpec::Mode::kEveryCycle;
    return {};
  }
  LFTRACK_RETURN_IF_ERROR(check_session_surrogate(p.scene, o));
  const SurrogateSpec& s = p.scene.surrogate;
  if (s.source == "sim") {
    if (parts->room == nullptr) return failed_precondition("surrogate.source sim needs the simulated room");
    parts->surrogate = parts->room->chest_marker();
  } else if (s.source == "igtl") {
    drivers::IgtlSurrogateOptions client = igtl_surrogate_options(p.scene);
    if (parts->room != nullptr && o.devices == SessionDevices::kSimulated) {
      auto port = parts->room->serve_chest_marker();
      if (!port.ok()) return port.status();
      client.host = "127.0.0.1";
      client.port = *port;
    }
    parts->surrogate = std::make_unique<drivers::IgtlSurrogateSource>(client);
  } else {
    return unsupported("surrogate.source " + s.source);
  }
  spdlog::info("imaging on demand: X-ray pairs at {:g} Hz, the {} correlation model in between; {}",
               imaging.xray_hz,
               imaging.model.order == CorrelationModelSpec::Order::kQuadratic ? "quadratic" : "linear",
               describe_imaging_dose(p));
  return {};
}

}  // namespace lftrack::session
