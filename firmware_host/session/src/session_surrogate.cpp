// The session's breathing surrogate and imaging dose (session_parts.hpp: make_session_surrogate).

#include <spdlog/spdlog.h>

#include "lftrack/host/scene_imaging_dose.hpp"
#include "session_parts.hpp"

namespace lftrack::host {

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
  const SurrogateSpec& s = p.scene.surrogate;
  if (s.source == "sim") {
    if (parts->room == nullptr || o.devices == SessionDevices::kScene)
      return failed_precondition(p.scene.where("surrogate") +
                                 ": surrogate.source sim is the simulated patient's chest marker, for "
                                 "lftrack sim; a treatment room's "
                                 "surrogate is an optical tracker (surrogate.source igtl)");
    parts->surrogate = std::make_unique<SimSurrogateSource>(s.sim, parts->room.get(), o.surrogate_faults);
  } else {
    return unsupported("surrogate.source " + s.source + " is not built yet");
  }
  spdlog::info("imaging on demand: X-ray pairs at {:g} Hz, the {} correlation model in between; {}",
               imaging.xray_hz,
               imaging.model.order == CorrelationModelSpec::Order::kQuadratic ? "quadratic" : "linear",
               describe_imaging_dose(p));
  return {};
}

}  // namespace lftrack::host
