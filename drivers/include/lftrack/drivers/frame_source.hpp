#pragma once
// Where frame pairs come from: V4L2 detectors, an archived sequence, or the simulator.
//
// The caller owns the FramePair and sizes its images once (open() says the shape); acquire()
// fills them in place, so a cycle allocates nothing.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "lftrack/drivers/device.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::drivers {

struct Frame {
  tracking::Image<std::uint16_t> pixels;  // raw counts, the whole detector
  std::uint32_t sequence = 0;             // the detector's frame counter
  std::int64_t timestamp_ns = 0;          // CLOCK_MONOTONIC, middle of the exposure
};

// A detector as a frame source, archive or replay knows it: its scene name and pixel size.
struct DetectorShape {
  std::string name;
  int rows = 0, cols = 0;
};

struct FramePair {
  std::vector<Frame> frames;  // one per detector, in the scene's order
};

// Who answered as a detector: where it was reached (a GigE camera's address as given, a V4L2
// device path) and the name the device gives itself (a GigE camera's device id, its serial
// number). Either is empty where the source cannot tell.
struct DetectorIdentity {
  std::string address;
  std::string id;
  // What times its frames, where the source says (GigeDetector::clock_source()); empty otherwise.
  std::string clock;
  bool clock_fell_back = false;  // the device clock was asked for and cannot be used
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // Outside the cycle. Sizes `pair` for this source (one frame per detector).
  virtual Status open(FramePair* pair) = 0;
  // The loop says when it wants the next pair exposed (CLOCK_MONOTONIC ns, or the loop's
  // simulated clock): a triggered detector arms its trigger, the simulator starts rendering.
  // Free-running sources ignore it. Never blocks.
  virtual void request_exposure(std::int64_t exposure_time_ns) { (void)exposure_time_ns; }
  // Instead of request_exposure: the cycle at `cycle_time_ns` takes no pair (imaging on demand
  // corrects it from a surrogate). The simulator moves its room on to that time; a device does
  // nothing. Never blocks.
  virtual void no_exposure(std::int64_t cycle_time_ns) { (void)cycle_time_ns; }
  // Whether a pair is exposed only when request_exposure() asks for one (the simulator's detectors):
  // imaging on demand needs it, or it saves no dose and may be handed a pair queued long before.
  virtual bool exposes_on_request() const { return false; }
  // In the cycle: fills `pair` with the next pair, or says why not by `deadline`.
  virtual DeviceStatus acquire(FramePair* pair, Deadline deadline) = 0;
  // True once a finite source (an archived sequence) has delivered its last pair; the loop
  // then ends instead of counting the missing frames as faults.
  virtual bool exhausted() const { return false; }
  // False for frames that show no patient in the room now (an archived sequence): the loop
  // permits no beam on them, and no actuator that moves a patient may be driven by them.
  virtual bool live() const { return true; }
  // Once open() has succeeded, outside the cycle: who answered as detector `detector` (the
  // scene's order). Empty where the source cannot tell (the default).
  virtual DetectorIdentity identity(std::size_t detector) const {
    (void)detector;
    return {};
  }
  virtual void close() = 0;
};

}  // namespace lftrack::drivers
