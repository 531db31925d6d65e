#pragma once
// Where the loop's breathing surrogate comes from (the loop's imaging_on_demand.hpp): the simulated
// patient's chest marker (host's sim_surrogate_source.hpp), or an optical tracker streaming over
// OpenIGTLink (igtl_surrogate.hpp). The loop asks once per cycle for
// the readings taken since it last asked; a source reads its device at its own rate on a thread of
// its own where it has one, and hands the readings over without allocating and without blocking.

#include <cstdint>

#include "lftrack/tracking/status.hpp"

namespace lftrack::drivers {

struct SurrogateReading {
  std::int64_t t_ns = 0;  // when it was measured, on the loop's clock (CLOCK_MONOTONIC in real time)
  double amplitude = 0;   // the marker's displacement along its main axis (mm)
};

class SurrogateSource {
 public:
  virtual ~SurrogateSource() = default;
  // Outside the cycle.
  virtual Status open() { return {}; }
  virtual void close() {}
  // In the cycle: the readings measured at or before `now_ns` that were not given before, oldest
  // first, at most `capacity` (the newest when there are more). Returns how many.
  virtual int read(std::int64_t now_ns, SurrogateReading* out, int capacity) = 0;
};

}  // namespace lftrack::drivers
