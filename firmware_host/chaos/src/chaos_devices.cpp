// The chaos soak's device wrappers: the surrogate, frame source and actuator that inject the
// injector's faults, and the operator who answers HOLDs at random (chaos_devices.hpp).

#include "chaos_devices.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <vector>

namespace lftrack::chaos {

int ChaosSurrogate::read(std::int64_t now_ns, drivers::SurrogateReading* out, int capacity) {
  int n = inner_->read(now_ns, out, capacity);
  const bool stopped_or_frozen =
      cycles_left_ > 0 && (active_ == ChaosFault::kSurrogateStop || active_ == ChaosFault::kSurrogateFreeze);
  if (const ChaosFault f = injector_->take_surrogate_fault(); f != ChaosFault::kCount) {
    std::mt19937_64& random = injector_->random();
    if (f == ChaosFault::kSurrogateStop || f == ChaosFault::kSurrogateFreeze ||
        f == ChaosFault::kSurrogateCough) {
      active_ = f;
      cycles_left_ = f == ChaosFault::kSurrogateStop     ? int(draw_uniform(random, 3, 16))
                     : f == ChaosFault::kSurrogateFreeze ? int(draw_uniform(random, 8, 21))
                                                         : 6;
      cough_cycle_ = 0;
      injector_->count(f);
      injector_->injection.what = to_string(f);
    } else if (!stopped_or_frozen && n >= (f == ChaosFault::kSurrogateNonFinite ? 1 : 2)) {
      // One reading, the cycle's newest; a spike beside its neighbour in the same batch (the
      // watch's jump is between neighbouring readings: the first after a gap has none). Not
      // while the stream is stopped or frozen, which would hide it; not counted where not given.
      out[n - 1].amplitude = f == ChaosFault::kSurrogateNonFinite ? std::numeric_limits<double>::quiet_NaN()
                                                                  : out[n - 2].amplitude + 3 * jump_;
      injector_->injection.surrogate_reading = true;
      injector_->count(f);
      injector_->injection.what = to_string(f);
    }
  }
  if (cycles_left_ > 0) {
    --cycles_left_;
    if (active_ == ChaosFault::kSurrogateStop) {
      n = 0;
    } else if (active_ == ChaosFault::kSurrogateFreeze) {
      for (int i = 0; i < n; ++i) out[i].amplitude = last_given_;
    } else {  // a cough: sin^2 over its cycles
      const double bump = std::sin(std::numbers::pi * (cough_cycle_ + 0.5) / 6.0);
      ++cough_cycle_;
      for (int i = 0; i < n; ++i) out[i].amplitude += 8.0 * bump * bump;
    }
  }
  if (n > 0 && std::isfinite(out[n - 1].amplitude) && !injector_->injection.surrogate_reading)
    last_given_ = out[n - 1].amplitude;
  return n;
}

// Once per cycle: a cycle planned without a pair that takes one after all (imaging on demand) is
// told no_exposure and then request_exposure for the same time.
void ChaosFrameSource::begin_cycle_at(std::int64_t time_ns) {
  if (first_exposure_ns_ < 0) first_exposure_ns_ = time_ns;
  const std::int64_t cycle = (time_ns - first_exposure_ns_ + period_ns_ / 2) / period_ns_;
  if (cycle == begun_cycle_) return;
  begun_cycle_ = cycle;
  injector_->begin_cycle(cycle);
}

void ChaosFrameSource::request_exposure(std::int64_t exposure_time_ns) {
  begin_cycle_at(exposure_time_ns);
  inner_->request_exposure(exposure_time_ns);
}

// A cycle without a pair (imaging on demand) is a cycle all the same: its faults are drawn.
void ChaosFrameSource::no_exposure(std::int64_t cycle_time_ns) {
  begin_cycle_at(cycle_time_ns);
  inner_->no_exposure(cycle_time_ns);
}

drivers::DeviceStatus ChaosFrameSource::acquire(drivers::FramePair* pair, drivers::Deadline deadline) {
  const ChaosFault fault = injector_->take_frame_fault();
  if (fault == ChaosFault::kFrameThrows) {
    injector_->count(fault);
    injector_->throw_into_loop("chaos: the frame source threw");
  }
  // The simulator's pair is always collected, so that its renderer stays in step.
  const drivers::DeviceStatus status = inner_->acquire(pair, deadline);
  if (status != drivers::DeviceStatus::kOk) {
    injector_->injection.frame_fault = true;  // a fault of its own: the same safe state
    injector_->injection.what = "the frame source's own failure";
    return status;
  }
  if (fault == ChaosFault::kCount) return status;
  injector_->count(fault);
  injector_->injection.frame_fault = true;
  injector_->injection.what = to_string(fault);
  std::vector<drivers::Frame>& frames = pair->frames;
  const SafetyLimits& limits = injector_->limits();
  switch (fault) {
    case ChaosFault::kFrameLost:
      return drivers::DeviceStatus::kTimeout;
    case ChaosFault::kFrameLate: {  // exposed well before the cycle asked: older than max_frame_age
      const auto late_ns = std::int64_t((1.2 * limits.max_frame_age_ms + 30) * 1e6);
      for (drivers::Frame& f : frames) f.timestamp_ns -= late_ns;
      break;
    }
    case ChaosFault::kFrameStale: {  // an exposure of a second (and the age limit) ago delivered again
      const auto stale_ns = std::int64_t((1000 + limits.max_frame_age_ms) * 1e6);
      for (drivers::Frame& f : frames) {
        f.timestamp_ns -= stale_ns;
        f.sequence -= 10;
      }
      break;
    }
    case ChaosFault::kFrameSkewed:  // views exposed further apart than a pair may be
      if (frames.size() > 1)
        frames[1].timestamp_ns += std::int64_t((2.5 * limits.max_pair_skew_ms + 5) * 1e6);
      break;
    case ChaosFault::kFrameBlank:
      for (drivers::Frame& f : frames) std::fill(f.pixels.pixels().begin(), f.pixels.pixels().end(), 0);
      break;
    case ChaosFault::kFrameSaturated:
      std::fill(frames[0].pixels.pixels().begin(), frames[0].pixels.pixels().end(), 0xFFFF);
      break;
    case ChaosFault::kFrameTorn: {
      tracking::Image<std::uint16_t>& image = frames[0].pixels;
      for (int r = image.rows() / 2; r < image.rows(); ++r)
        for (int c = 0; c < image.cols(); ++c) image.at(r, c) = 0;
      break;
    }
    case ChaosFault::kFrameDisconnected:
      return drivers::DeviceStatus::kDisconnected;
    case ChaosFault::kFrameDeviceFault:
      return drivers::DeviceStatus::kFault;
    default:
      break;
  }
  return drivers::DeviceStatus::kOk;
}

drivers::DeviceStatus ChaosActuator::command(const tracking::Vector6d& correction,
                                             drivers::Deadline deadline) {
  ActuatorCalls& calls = injector_->calls;
  if (!correction.allFinite()) calls.non_finite = true;
  const ChaosFault fault = injector_->take_command_fault();
  if (fault != ChaosFault::kCount) injector_->count(fault);
  if (fault == ChaosFault::kCommandThrows) injector_->throw_into_loop("chaos: the actuator's command threw");
  if (fault != ChaosFault::kCount) {
    // The device may or may not have taken it before the line failed.
    if (injector_->random()() % 2 == 0) (void)inner_->command(correction, deadline);
    ++calls.commands_failed;
    injector_->injection.command_fault = true;
    injector_->injection.what = to_string(fault);
    return fault == ChaosFault::kCommandTimeout        ? drivers::DeviceStatus::kTimeout
           : fault == ChaosFault::kCommandDisconnected ? drivers::DeviceStatus::kDisconnected
                                                       : drivers::DeviceStatus::kFault;
  }
  const drivers::DeviceStatus status = inner_->command(correction, deadline);
  if (status == drivers::DeviceStatus::kOk) {
    ++calls.commands_accepted;
    calls.last_command = correction;
    known_target_ += correction;
    calls.target_after = known_target_;
  } else {
    ++calls.commands_failed;
    injector_->injection.command_fault = true;
    injector_->injection.what = "the actuator's own command failure";
  }
  return status;
}

drivers::DeviceStatus ChaosActuator::readback(drivers::ActuatorState* state, drivers::Deadline deadline) {
  const bool first = readback_cycle_ != injector_->cycle();
  readback_cycle_ = injector_->cycle();
  const ChaosFault fault = first ? injector_->take_readback_fault() : ChaosFault::kCount;
  if (fault == ChaosFault::kReadbackThrows) {
    injector_->count(fault);
    injector_->throw_into_loop("chaos: the actuator's read-back threw");
  }
  const drivers::DeviceStatus status = inner_->readback(state, deadline);
  if (status == drivers::DeviceStatus::kOk && state->target.allFinite()) {
    known_target_ = state->target;
    injector_->calls.target_after = known_target_;
  }
  if (first && status == drivers::DeviceStatus::kOk) {  // the loop's read-back at the frames' exposure
    injector_->calls.have_readback = true;
    injector_->calls.travel_left = state->target - state->position;
  }
  if (first && status != drivers::DeviceStatus::kOk) {
    injector_->injection.readback_fault = true;
    injector_->injection.what = "the actuator's own read-back failure";
  }
  if (fault == ChaosFault::kCount || status != drivers::DeviceStatus::kOk) return status;
  injector_->count(fault);
  injector_->injection.readback_fault = true;
  injector_->injection.what = to_string(fault);
  std::mt19937_64& random = injector_->random();
  switch (fault) {
    case ChaosFault::kReadbackTimeout:
      return drivers::DeviceStatus::kTimeout;
    case ChaosFault::kReadbackDisconnected:
      return drivers::DeviceStatus::kDisconnected;
    case ChaosFault::kReadbackFaultFlag:
      state->fault = true;
      break;
    case ChaosFault::kReadbackMismatch: {  // along one axis, 2 to 10 times the tolerance
      const int axis = int(random() % 3);
      const double sign = random() % 2 == 0 ? 1.0 : -1.0;
      const double offset =
          sign * draw_uniform(random, 2.0, 10.0) * injector_->limits().readback_tolerance_mm;
      state->position[axis] += offset;
      state->target[axis] += offset;
      break;
    }
    case ChaosFault::kReadbackNonFinite:
      state->position[0] = std::numeric_limits<double>::quiet_NaN();
      if (random() % 2 == 0) state->target[1] = std::numeric_limits<double>::quiet_NaN();
      break;
    default:
      break;
  }
  return drivers::DeviceStatus::kOk;
}

void ChaosActuator::hold() {
  inner_->hold();
  if (injector_->threw) injector_->held_after_throw = true;
}

void ChaosActuator::set_beam_permit(bool permit) {
  injector_->calls.beam_permit = permit;
  if (injector_->threw) injector_->beam_dropped_after_throw = !permit;
  inner_->set_beam_permit(permit);
}

void ChaosOperator::poll(const OperatorView& view, OperatorPoll* out) {
  std::mt19937_64& random = injector_->random();
  const bool held = view.state == TrackingState::kHold || view.state == TrackingState::kFault;
  if (held && view.hold_id != 0) {
    if (view.hold_id != planned_for_) {
      planned_for_ = view.hold_id;
      answer_at_s_ = draw_uniform(random, 0.2, 3.0);
      mistake_ = draw_uniform(random, 0, 1) < 0.1;
      answered_ = false;
    }
    if (!answered_ && view.hold_age_s >= answer_at_s_) {
      OperatorRequest request;
      request.command =
          view.state == TrackingState::kHold ? OperatorCommand::kResume : OperatorCommand::kReset;
      request.names_hold = true;
      request.hold_id = view.hold_id;
      if (mistake_ && random() % 2 == 0)
        request.hold_id = view.hold_id == 999999 ? 100000 : view.hold_id + 1;  // another HOLD's id
      else if (mistake_)
        request.command =
            request.command == OperatorCommand::kResume ? OperatorCommand::kReset : OperatorCommand::kResume;
      const OperatorRefusal why = judge_operator_request(request, view, /*id_required=*/true);
      if (why == OperatorRefusal::kNone) {
        out->accept(request.command);
        answered_ = true;
        injector_->action.accepted = true;
        injector_->action.named_id = request.hold_id;
      } else {
        out->refuse(why);
        mistake_ = false;
        answer_at_s_ = view.hold_age_s + 0.5;
      }
    }
  } else if (view.state == TrackingState::kTrack && draw_uniform(random, 0, 1) < 0.002) {
    OperatorRequest stale;  // a resume sent for a HOLD that is over
    stale.command = OperatorCommand::kResume;
    stale.names_hold = true;
    stale.hold_id = last_hold_id_ != 0 ? last_hold_id_ : 123456;
    const OperatorRefusal why = judge_operator_request(stale, view, /*id_required=*/true);
    if (why == OperatorRefusal::kNone) {
      out->accept(stale.command);
      injector_->action.accepted = true;
      injector_->action.named_id = stale.hold_id;
    } else {
      out->refuse(why);
    }
  }
  if (view.hold_id != 0) last_hold_id_ = view.hold_id;
}

}  // namespace lftrack::chaos
