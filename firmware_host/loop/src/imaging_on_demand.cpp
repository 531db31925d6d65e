// Imaging on demand (imaging_on_demand.hpp): when a cycle takes a pair, and the surrogate's watch.

#include "lftrack/loop/imaging_on_demand.hpp"

#include <cmath>

namespace lftrack::loop {

const char* to_string(ImagingReason reason) {
  switch (reason) {
    case ImagingReason::kNone:
      return "model";
    case ImagingReason::kEveryCycle:
      return "every cycle";
    case ImagingReason::kScheduled:
      return "scheduled";
    case ImagingReason::kOutsideFit:
      return "surrogate outside the model's range";
    case ImagingReason::kConfirmMiss:
      return "confirming a refitted model";
    case ImagingReason::kModelStale:
      return "model not confirmed recently";
    case ImagingReason::kBuildingModel:
      return "building the model";
  }
  return "?";
}

const char* to_string(SurrogateFault fault) {
  switch (fault) {
    case SurrogateFault::kOk:
      return "ok";
    case SurrogateFault::kNoReadings:
      return "no surrogate readings";
    case SurrogateFault::kStale:
      return "surrogate stopped";
    case SurrogateFault::kJump:
      return "surrogate jumped";
    case SurrogateFault::kFrozen:
      return "surrogate frozen";
    case SurrogateFault::kNotFinite:
      return "surrogate reading not finite";
  }
  return "?";
}

ImagingReason next_imaging(const ImagingSpec& spec, const ImagingState& state, std::int64_t start_ns,
                           std::int64_t period_ns) {
  if (!spec.model_mode() || !state.tracking) return ImagingReason::kEveryCycle;
  if (!state.model_ready) return ImagingReason::kBuildingModel;
  if (state.miss_pending) return ImagingReason::kConfirmMiss;
  if (!state.surrogate_within_fit) return ImagingReason::kOutsideFit;
  if (pair_due(spec, state, start_ns, period_ns)) return ImagingReason::kScheduled;
  if (state.last_agreed_ns >= 0 && double(start_ns - state.last_agreed_ns) >= spec.stale_s * 1e9)
    return ImagingReason::kModelStale;
  return ImagingReason::kNone;
}

bool pair_due(const ImagingSpec& spec, const ImagingState& state, std::int64_t exposure_ns,
              std::int64_t period_ns) {
  return state.last_pair_ns < 0 ||
         double(exposure_ns - state.last_pair_ns) + 0.5 * double(period_ns) >= 1e9 / spec.xray_hz;
}

void SurrogateMonitor::reset() {
  jumped_ = not_finite_ = false;
  changed_ns_ = newest_ns_;  // the freeze clock starts again; the newest reading is kept
}

void SurrogateMonitor::on_reading(std::int64_t t_ns, double amplitude) {
  if (!std::isfinite(amplitude)) {
    not_finite_ = true;
    return;
  }
  not_finite_ = false;
  if (readings_ > 0 && t_ns <= newest_ns_) return;  // not newer: the stream refuses it too
  if (readings_ == 0 || amplitude != newest_) changed_ns_ = t_ns;
  // A jump between neighbouring readings only: across a gap (a long cycle that dropped readings)
  // a breath moves further than any jump limit, and the gap itself is the stale check's.
  const double neighbours_ns = 3e9 / limits_.rate_hz;
  if (readings_ > 0 && double(t_ns - newest_ns_) <= neighbours_ns &&
      std::abs(amplitude - newest_) > limits_.jump)
    jumped_ = true;
  newest_ = amplitude;
  newest_ns_ = t_ns;
  ++readings_;
}

SurrogateFault SurrogateMonitor::fault_at(std::int64_t now_ns) const {
  if (not_finite_) return SurrogateFault::kNotFinite;
  if (jumped_) return SurrogateFault::kJump;
  if (readings_ == 0) return SurrogateFault::kNoReadings;
  if (double(now_ns - newest_ns_) > limits_.stale_ms * 1e6) return SurrogateFault::kStale;
  if (double(newest_ns_ - changed_ns_) >= limits_.freeze_s * 1e9) return SurrogateFault::kFrozen;
  return SurrogateFault::kOk;
}

}  // namespace lftrack::loop
