#pragma once
// The simulated patient's chest marker (sim::BreathingSurrogate) as the loop's SurrogateSource
// (surrogate_source.hpp): a reading every 1 / sample_rate_hz on the room's clock (t = 0 at the
// room's first exposure), up to the time the loop asks for. The readings are a function of time,
// so they are computed when asked, on the loop's thread; a simulated run stays deterministic from
// its seed. (A device's source, OpenIGTLink, reads on a thread of its own.)
//
// Faults, for tests and the chaos soak (times in seconds on the room's clock; negative: none): a
// marker that freezes (repeats its last reading), a stream that stops, a cough (the marker rises
// by cough_mm over cough_s, the target does not follow the model), and a marker that slides on the
// skin (the surrogate drifts from the target at slide_mm_per_s).

#include <cstdint>

#include "lftrack/drivers/surrogate_source.hpp"
#include "lftrack/session/room_simulator.hpp"
#include "lftrack/sim/breathing_surrogate.hpp"
#include "lftrack/sim/simulated_room.hpp"

namespace lftrack::sim_devices {

class SimSurrogateSource final : public drivers::SurrogateSource {
 public:
  SimSurrogateSource(const sim_spec::BreathingSurrogateSpec& spec, const sim::SimulatedRoom* room,
                     const session::SimSurrogateFaults& faults = {});
  int read(std::int64_t now_ns, drivers::SurrogateReading* out, int capacity) override;
  // The marker's reading at t_s on the room's clock, faults included (the next draw of the noise).
  double reading_at(double t_s);
  // Whether the stream has stopped by t_s (the stop fault): no reading is given from then on.
  bool stopped_at(double t_s) const { return faults_.stop_from_s >= 0 && t_s >= faults_.stop_from_s; }

 private:
  sim::BreathingSurrogate chest_;
  const sim::SimulatedRoom* room_;
  session::SimSurrogateFaults faults_;
  std::int64_t next_ = 0;  // the next reading's index
  double frozen_ = 0;
  bool have_frozen_ = false;
};

}  // namespace lftrack::sim_devices
