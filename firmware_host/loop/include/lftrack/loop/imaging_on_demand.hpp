#pragma once
// Imaging on demand (issue 58): the loop follows an external breathing surrogate between sparse
// X-ray pairs, through a correlation model fitted to them (correlation_model.hpp), as CyberKnife
// Synchrony, Vero and KIM do. `tracking.imaging` in a scene:
//   every_cycle  every cycle takes a pair and registers it (the default);
//   model        TRACK cycles take a pair only when one is due (ImagingReason); the others correct
//                from the model's prediction at the newest surrogate reading.
// Until the model is ready (a breathing cycle of pairs at xray_hz, correlation_model.hpp) every TRACK
// cycle takes a pair, as without a model, and the model takes one of them at xray_hz: corrections a
// second apart would move the patient by the breathing's whole travel at once (beyond the gate's
// step limit), and a model fitted from pairs 0.1 s apart never spans a breath in its window. Then a
// pair is due at `xray_hz`; early when the surrogate leaves the amplitudes and rates the model
// was fitted on (a cough, a deep breath), when the last check missed (the refitted model is
// confirmed at once), and when no pair has confirmed the model for `stale_s`. ALIGN and HOLD take a
// pair every cycle, as without a model: the alignment, and the offset the operator decides on.
//
// The surrogate is watched as frames are (SurrogateMonitor): a stream that stops (no reading for
// stale_ms), jumps (two readings further apart than jump) or freezes (no change for freeze_s) HOLDs
// the loop in TRACK at once (GateReason::kSurrogateStopped, ...Jumped, ...Frozen, ...NotFinite),
// whatever the cycle images. Not counted
// like a lost frame, whose next pair is a period away: the cycles between X-ray pairs have nothing
// else to follow, a tracker that lost its marker rarely finds it in a cycle, and the skipped cycles
// of a deep breath would make the next correction a jump beyond the step limit (which then holds
// for a reason that hides the cause). A model whose check misses twice in a row HOLDs at once
// (GateReason::kModelMissed).
//
// Dose: every pair costs `dose_per_pair_mGy` of skin entrance dose (the session computes it from the
// scene's technique, scene_imaging_dose.hpp); the summary counts pairs and their dose.

#include <cstdint>

#include "lftrack/loop/correlation_model.hpp"

namespace lftrack::loop {

struct SurrogateLimits {
  double rate_hz = 60;    // the source's reading rate (its rate is taken over a window of readings)
  double stale_ms = 100;  // the newest reading older than this at the cycle: stopped
  double jump = 5;        // between two consecutive readings (the surrogate's unit, mm for a marker)
  double freeze_s = 0.5;  // the reading has not changed for this long: frozen (a tracker repeats
                          // its last value when it loses the marker; a live one has noise)
};

struct ImagingSpec {
  enum class Mode { kEveryCycle, kModel };
  Mode mode = Mode::kEveryCycle;
  double xray_hz = 1.0;  // pairs per second in TRACK (model)
  double stale_s = 3.0;  // the model's last confirmation older than this: a pair
  CorrelationModelSpec model;
  SurrogateLimits surrogate;
  double dose_per_pair_mGy = 0;  // skin entrance, every view's field added (0: not known)
  bool model_mode() const { return mode == Mode::kModel; }
};

// Why a cycle takes a pair (kNone: it corrects from the model). Journaled (JournalRecord::imaging).
enum class ImagingReason : std::uint8_t {
  kNone = 0,           // a model cycle: no pair
  kEveryCycle = 1,     // tracking.imaging every_cycle, or ALIGN / HOLD
  kScheduled = 2,      // xray_hz
  kOutsideFit = 3,     // the surrogate left the model's range (a cough): an early pair
  kConfirmMiss = 4,    // the last check missed and the model was refitted: confirm at once
  kModelStale = 5,     // no agreeing check for stale_s
  kBuildingModel = 6,  // the model is not ready: every cycle, the model takes one at xray_hz
};
const char* to_string(ImagingReason reason);

// What the next cycle needs to know to decide.
struct ImagingState {
  bool tracking = false;  // the loop is in TRACK (ALIGN and HOLD image every cycle)
  bool model_ready = false;
  bool surrogate_within_fit = false;  // the newest reading, against the model's fitted range
  bool miss_pending = false;          // the last check missed (refitted)
  std::int64_t last_pair_ns = -1;     // the exposure of the last pair the model took (-1: none)
  std::int64_t last_agreed_ns = -1;   // the last check that agreed, or the model's first fit
};

// Whether the cycle starting at `start_ns` (period `period_ns`) takes a pair, and why. A scheduled
// pair is due within half a period of 1/xray_hz after the last, so that 1 Hz at a 100 ms period is
// every tenth cycle, not every eleventh.
ImagingReason next_imaging(const ImagingSpec& spec, const ImagingState& state, std::int64_t start_ns,
                           std::int64_t period_ns);
// Whether a pair exposed at `exposure_ns` is due to the model at xray_hz (see next_imaging).
bool pair_due(const ImagingSpec& spec, const ImagingState& state, std::int64_t exposure_ns,
              std::int64_t period_ns);

// Why the surrogate fails a cycle (kOk: it does not). Journaled (JournalRecord::surrogate_fault).
enum class SurrogateFault : std::uint8_t { kOk = 0, kNoReadings, kStale, kJump, kFrozen, kNotFinite };
const char* to_string(SurrogateFault fault);

// Watches the surrogate's readings, one by one as the loop takes them: stopped, jumped (between
// readings at most three reading intervals apart), frozen. A jump stays until reset() (the relation
// between the marker and the target is unknown after it: a marker that slid, a tracker that
// swapped markers); the operator's resume resets, keeping the newest reading.
// Allocates nothing.
class SurrogateMonitor {
 public:
  explicit SurrogateMonitor(const SurrogateLimits& limits) : limits_(limits) {}
  void reset();
  void on_reading(std::int64_t t_ns, double amplitude);
  // At the cycle's decision, on the loop's clock.
  SurrogateFault fault_at(std::int64_t now_ns) const;

 private:
  SurrogateLimits limits_;
  std::int64_t readings_ = 0;
  std::int64_t newest_ns_ = 0, changed_ns_ = 0;
  double newest_ = 0;
  bool jumped_ = false, not_finite_ = false;
};

}  // namespace lftrack::loop
