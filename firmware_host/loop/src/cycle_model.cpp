// Imaging on demand in the cycle (imaging_on_demand.hpp): the surrogate's readings, the cycle
// without a pair, the model checked by each pair or giving the offset, and the next cycle's pair.

#include "lftrack/loop/cycle_schedule.hpp"
#include "loop_impl.hpp"

namespace lftrack::loop {

using tracking::Pose;
using tracking::PoseDelta;
using tracking::Vector6d;

// Every reading since the last cycle, through the watch and into the stream; the newest, with its
// rate, is the cycle's surrogate. Readings are taken at the cycle's start: the pair's exposure.
void TrackingLoop::Impl::read_surrogate(CycleState& c) {
  if (!settings.loop.imaging.model_mode() || parts.surrogate == nullptr) return;
  const std::int64_t now = clock->now_ns(c.start_ns);
  const int n = parts.surrogate->read(now, surrogate_readings.data(), int(surrogate_readings.size()));
  for (int i = 0; i < n; ++i) {
    const drivers::SurrogateReading& r = surrogate_readings[std::size_t(i)];
    surrogate_monitor.on_reading(r.t_ns, r.amplitude);
    (void)surrogate_stream.push(r.t_ns, r.amplitude);
  }
  c.surrogate_fault = surrogate_monitor.fault_at(now);
  c.surrogate_read = surrogate_stream.newest(&c.surrogate);
  if (c.surrogate_read && c.surrogate_fault == SurrogateFault::kOk) model.observe(c.surrogate);
  // The surrogate counts in TRACK: the loop treats from it. ALIGN and HOLD image every cycle.
  c.gate_input.surrogate_fault = c.state == TrackingState::kTrack ? c.surrogate_fault : SurrogateFault::kOk;
}

// A cycle without a pair: the actuator's read-back (and the simulated truth) as acquire() takes
// them, and nothing of frames.
void TrackingLoop::Impl::without_pair(CycleState& c) {
  c.acquire_started_ns = monotonic_now_ns();
  read_back(c);
  c.acquired_ns = c.preprocessed_ns = monotonic_now_ns();
  cycle_wall_start_ns = clock->work_started_ns(cycle_wall_start_ns, c.acquired_ns);
  c.oldest_frame_ns = c.newest_frame_ns = c.surrogate_read ? c.surrogate.t_ns : c.start_ns;
  GateInput& in = c.gate_input;
  in.views = 0;
  in.frames_ok = true;
  in.model_cycle = true;
  in.journal_ok = parts.journal == nullptr || !parts.journal->failed();
  in.consecutive_overruns = consecutive_overruns;
}

// A registered pair in TRACK checks the model at the surrogate of its exposure; a second miss in a
// row holds (the gate). ALIGN's and HOLD's pairs are not the treatment's: the model waits for TRACK.
void TrackingLoop::Impl::check_model(CycleState& c, const Vector6d& patient_offset) {
  last_patient_offset = patient_offset;
  if (!settings.loop.imaging.model_mode() || c.state != TrackingState::kTrack) return;
  // While the model is built every cycle takes a pair; the model takes them at xray_hz.
  if (c.imaging == ImagingReason::kBuildingModel &&
      !pair_due(settings.loop.imaging, imaging_state, c.newest_frame_ns, period_ns))
    return;
  if (!c.surrogate_read || c.surrogate_fault != SurrogateFault::kOk) return;  // the gate holds
  // A registration cut short by its time budget (the real clock) may have stopped near its start,
  // which is the model's own prediction (register_pair): it would confirm the model it checks.
  if (result.stop == tracking::OptimizerStop::kTimeBudget) return;
  // A pair taken because the surrogate left the model's range measures the target where the model
  // extrapolates. Near the range (within kWidenMargin of its span), where the extrapolation still
  // agrees, the pair widens it: a breath deeper than the steady X-rays had caught (at 1 Hz in a 4 s
  // breath they see four phases). Further out (a cough, a gasp), or where it does not agree, the
  // registration corrects, and the model neither counts a miss nor takes the pair: one pair far out
  // would tilt a fit of twenty.
  constexpr double kWidenMargin = 0.3;
  const bool was_ready = model.ready();
  const Eigen::Vector3d predicted = model.predict(c.surrogate);  // NaN when not ready
  if (c.imaging == ImagingReason::kOutsideFit &&
      (!model.within(c.surrogate, kWidenMargin) ||
       !((predicted - patient_offset.head<3>()).norm() <= settings.loop.imaging.model.tolerance_mm)))
    return;
  imaging_state.last_pair_ns = c.newest_frame_ns;
  if (was_ready) c.model_checked_prediction = predicted;
  c.model_check = model.check(c.surrogate, patient_offset.head<3>());
  c.model_checked = true;
  const bool agreed = c.model_check == CorrelationModel::Check::kAgrees ||
                      (!was_ready && c.model_check == CorrelationModel::Check::kNotReady && model.ready());
  if (agreed) imaging_state.last_agreed_ns = c.start_ns;
  imaging_state.miss_pending = c.model_check == CorrelationModel::Check::kMissRefitted;
  c.gate_input.model_missed = c.model_check == CorrelationModel::Check::kMissAgain;
}

// The model's target position at the cycle's surrogate, with the rotation of the last registration,
// when the model is ready and the reading lies within what it was fitted on.
bool TrackingLoop::Impl::model_offset(const CycleState& c, Vector6d* patient_offset) const {
  if (c.state != TrackingState::kTrack || !c.surrogate_read || c.surrogate_fault != SurrogateFault::kOk ||
      !model.ready() || !model.within_fit(c.surrogate))
    return false;
  const Eigen::Vector3d at = model.predict(c.surrogate);
  if (!at.allFinite()) return false;
  *patient_offset = last_patient_offset;
  patient_offset->head<3>() = at;
  return true;
}

bool TrackingLoop::Impl::pair_needed_now(const CycleState& c) const {
  if (c.state != TrackingState::kTrack) return true;
  if (c.surrogate_fault != SurrogateFault::kOk) return false;  // the gate holds
  tracking::Vector6d offset;
  return !model_offset(c, &offset);  // the model cannot say at this reading (model_offset's own rules)
}

void TrackingLoop::Impl::restart_model() {
  model.reset();
  surrogate_monitor.reset();
  surrogate_stream.reset();
  imaging_state = ImagingState{};
}

void TrackingLoop::Impl::plan_next_exposure(std::int64_t start_ns) {
  imaging_state.tracking = machine.state() == TrackingState::kTrack;
  imaging_state.model_ready = model.ready();
  imaging_state.surrogate_within_fit = cycle_state.surrogate_read && model.within_fit(cycle_state.surrogate);
  next_imaging_reason = next_imaging(settings.loop.imaging, imaging_state, start_ns, period_ns);
  if (next_imaging_reason == ImagingReason::kNone)
    parts.frames->no_exposure(start_ns);
  else
    parts.frames->request_exposure(start_ns);
}

}  // namespace lftrack::loop
