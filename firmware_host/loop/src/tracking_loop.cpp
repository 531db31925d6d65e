// The real-time loop (tracking_loop.hpp): create() sizes everything; run() keeps the period and
// runs one cycle per period, stage by stage (cycle_stages.cpp), journals each cycle's record
// (cycle_record.cpp) and gathers the statistics from it.

#include "lftrack/loop/tracking_loop.hpp"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "lftrack/loop/cycle_schedule.hpp"
#include "lftrack/loop/time_interval.hpp"
#include "loop_impl.hpp"

namespace lftrack::loop {

using drivers::DeviceStatus;

drivers::Deadline to_deadline(std::int64_t ns) {
  return drivers::Deadline(
      std::chrono::duration_cast<drivers::Deadline::duration>(std::chrono::nanoseconds(ns)));
}

double ms_between(std::int64_t a_ns, std::int64_t b_ns) { return 1e-6 * ns_between(a_ns, b_ns); }

std::int64_t loop_period_ns(const LoopSettings& s) {
  return static_cast<std::int64_t>(std::llround(s.loop.period_ms * 1e6));
}

double prediction_lookahead_s(const LoopSettings& s) {
  return s.loop.lookahead_s.value_or(1e-9 * double(loop_period_ns(s)) + s.actuator_latency_s);
}

TrackingLoop::TrackingLoop(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
TrackingLoop::~TrackingLoop() {
  if (impl_ && impl_->parts.frames != nullptr) impl_->parts.frames->close();
  if (impl_ && impl_->parts.surrogate != nullptr && impl_->settings.loop.imaging.model_mode())
    impl_->parts.surrogate->close();
}

Result<std::unique_ptr<TrackingLoop>> TrackingLoop::create(const LoopParts& parts,
                                                           const LoopSettings& settings) {
  if (parts.registration == nullptr || parts.frames == nullptr)
    return invalid_argument("tracking loop: needs a registration and a frame source");
  const std::size_t views = parts.geometry.views.size();
  if (views == 0 || views > std::size_t(kMaxGateViews))
    return invalid_argument("tracking loop: 1 to 4 detectors");
  if (parts.geometry.roi_windows.size() != views)
    return invalid_argument("tracking loop: one ROI window per detector");
  if (parts.corrections.size() != views)
    return invalid_argument("tracking loop: one detector correction per detector");
  if (!(settings.loop.period_ms > 0)) return invalid_argument("tracking loop: the period must be positive");
  if (!parts.frames->live() && parts.actuator != nullptr && parts.actuator->moves_patient())
    return failed_precondition(
        "tracking loop: archived frames cannot move a patient (they show one who is no longer there); track "
        "and report them with no actuator, or with their recorded read-backs");
  auto impl = std::make_unique<Impl>();
  impl->parts = parts;
  impl->settings = settings;
  impl->clock = settings.simulated_clock ? simulated_cycle_clock(parts.observer) : host_cycle_clock();
  impl->period_ns = loop_period_ns(settings);
  impl->origin_room = parts.geometry.registration_origin_room_mm;
  impl->nominal = parts.geometry.nominal_T_room_from_ct;
  auto align = tracking::registration_plan(settings.loop.align_plan);
  if (!align.ok()) return align.status();
  auto track = tracking::registration_plan(settings.loop.track_plan);
  if (!track.ok()) return track.status();
  LFTRACK_RETURN_IF_ERROR(parts.registration->prepare(*align, *track));
  const ImagingSpec& imaging = settings.loop.imaging;
  if (imaging.model_mode()) {
    if (parts.surrogate == nullptr)
      return invalid_argument(
          "tracking loop: tracking.imaging model needs a breathing surrogate (the scene's `surrogate`)");
    if (!(imaging.xray_hz > 0 && imaging.xray_hz <= 1e3 / settings.loop.period_ms))
      return invalid_argument(
          "tracking loop: tracking.imaging.xray_hz must be above 0 and at most the loop's rate");
    if (!(imaging.stale_s > 0 && std::isfinite(imaging.stale_s)))
      return invalid_argument("tracking loop: tracking.imaging.stale_s must be positive");
    LFTRACK_RETURN_IF_ERROR(
        check_correlation_model_spec(imaging.model).with_context("tracking.imaging.model"));
    if (double(CorrelationModel::kCapacity - 1) < 1.25 * imaging.model.min_span_s * imaging.xray_hz)
      return invalid_argument(
          "tracking loop: at tracking.imaging.xray_hz the model's pairs cannot span its min_span_s");
    if (!(imaging.surrogate.rate_hz > 0 && imaging.surrogate.rate_hz <= 1000))
      return invalid_argument("tracking loop: the surrogate's rate must be above 0 and at most 1000 Hz");
    CorrelationModelSpec model = imaging.model;
    model.window = model_window_at(imaging.model, imaging.xray_hz);
    impl->model = CorrelationModel(model);
    impl->surrogate_monitor = SurrogateMonitor(imaging.surrogate);
    impl->surrogate_stream = SurrogateStream(rate_window_at(imaging.surrogate.rate_hz));
  }
  impl->predictor = MotionPredictor(settings.loop.prediction_cycles, settings.loop.prediction_order,
                                    prediction_lookahead_s(settings), settings.loop.predict_rotations);

  LFTRACK_RETURN_IF_ERROR(parts.frames->open(&impl->pair).with_context("frame source"));
  if (impl->pair.frames.size() != views)
    return failed_precondition("frame source: wrong number of detectors");
  for (std::size_t v = 0; v < views; ++v) {
    const tracking::PixelWindow& w = parts.geometry.roi_windows[v];
    impl->line_integral.emplace_back(w.rows, w.cols);
    impl->valid.emplace_back(w.rows, w.cols);
    impl->check_drr.emplace_back(w.rows, w.cols);
    impl->check_valid.emplace_back(w.rows, w.cols);
  }
  impl->view_issue.assign(views, tracking::FrameQualityIssue::kOk);
  impl->view_preprocessed.assign(views, 0);
  for (std::size_t v = 0; v < views; ++v) {
    impl->frame_views.push_back(impl->line_integral[v].view());
    impl->mask_views.push_back(impl->valid[v].view());
  }
  if (parts.feed != nullptr)
    LFTRACK_RETURN_IF_ERROR(parts.feed->allocate(impl->pair, parts.geometry.roi_windows).with_context("cycle feed"));
  impl->result.view_similarity.reserve(views);
  impl->summary.transitions.reserve(256);
  if (imaging.model_mode()) {
    if (!parts.frames->exposes_on_request())
      return failed_precondition(
          "tracking loop: tracking.imaging model needs detectors that expose only when asked (the "
          "simulator's); "
          "these expose on their own, which saves no dose and may hand over a pair queued long before");
    // Last: nothing after it can fail, so a source with a thread of its own is never left open.
    LFTRACK_RETURN_IF_ERROR(parts.surrogate->open().with_context("breathing surrogate"));
  }
  return std::unique_ptr<TrackingLoop>(new TrackingLoop(std::move(impl)));
}

bool TrackingLoop::Impl::cycle(std::int64_t index, std::int64_t start_ns, JournalRecord* record) {
  CycleState& c = cycle_state;
  c = CycleState{};
  c.index = index;
  c.start_ns = start_ns;
  c.state_before = machine.state();
  if (!take_operator_command(c)) {  // stop or quit: the actuator is held, nothing else runs
    c.state_after = machine.state();
    c.hold_id = hold_id;
    if (parts.actuator != nullptr) parts.actuator->set_beam_permit(false);
    *record = record_of(c);
    return false;
  }
  read_surrogate(c);
  c.imaging = next_imaging_reason;
  if (c.imaging == ImagingReason::kNone && pair_needed_now(c)) {
    // Planned without a pair, but an operator's command has taken the loop out of TRACK (ALIGN and
    // HOLD take a pair every cycle), or the newest reading lies where the model cannot say (a cough
    // begins): a pair now, exposed as late as the cycle's start allows, rather than a skipped cycle
    // after which the breath has moved on further than a step may go.
    parts.frames->request_exposure(c.start_ns);
    c.imaging = c.state != TrackingState::kTrack ? ImagingReason::kEveryCycle : ImagingReason::kOutsideFit;
  }
  if (c.imaging != ImagingReason::kNone) {
    if (!acquire(c)) return false;  // an archived sequence has ended: not a cycle
    preprocess(c);
    register_pair(c);
    judge(c);
  } else {
    without_pair(c);
  }
  c.registered_ns = monotonic_now_ns();
  control(c);
  gate(c);
  c.gated_ns = monotonic_now_ns();
  actuate(c);
  advance(c);
  settle(c);
  *record = record_of(c);
  gather_statistics(*record, c);
  ++cycles_in_state;
  return true;
}

void TrackingLoop::Impl::publish_to_feed(const JournalRecord& record) {
  CycleFeed& feed = *parts.feed;
  const CycleState& c = cycle_state;
  feed.publish_record(record, c.registered);
  if (!c.frames_usable || !feed.images_due(c.start_ns)) return;
  const tracking::Pose& shown = c.registered ? result.T_room_from_ct : have_registration ? last_registered : nominal;
  feed.publish_images(c.index, c.start_ns, c.registered, shown, pair, line_integral, valid);
}

void TrackingLoop::Impl::hold_actuator(std::int64_t deadline_ns) {
  if (parts.actuator == nullptr) return;
  parts.actuator->hold();
  drivers::ActuatorState state;
  target_unknown = true;
  if (parts.actuator->readback(&state, to_deadline(deadline_ns)) == DeviceStatus::kOk && !state.fault &&
      state.target.allFinite() && state.position.allFinite()) {
    commanded_total = state.target;
    couch_position = state.position;
    target_unknown = false;
  }
}

void TrackingLoop::Impl::hold_after_exception() noexcept {
  if (parts.actuator == nullptr) return;
  try {
    parts.actuator->hold();
  } catch (...) {  // the beam permit is dropped below whatever hold() did
  }
  try {
    parts.actuator->set_beam_permit(false);
  } catch (...) {  // nothing more can be done here; the error propagates
  }
}

bool TrackingLoop::Impl::result_is_finite() const {
  if (!result.T_room_from_ct.matrix().allFinite()) return false;
  for (double s : result.view_similarity)
    if (!std::isfinite(s)) return false;
  return result.stop != tracking::OptimizerStop::kNonFinite;
}

Result<LoopSummary> TrackingLoop::run() {
  Impl& m = *impl_;
  try {
    return run_cycles();
  } catch (...) {
    // Like libfranka's control loop: whatever a cycle throws (bad_alloc included), the actuator
    // is held and the beam permit dropped before the error reaches the caller.
    m.hold_after_exception();
    throw;
  }
}

Result<LoopSummary> TrackingLoop::run_cycles() {

  Impl& m = *impl_;
  const CycleClock& clock = *m.clock;
  const std::int64_t period = m.period_ns;
  const std::int64_t loop_start_ns = monotonic_now_ns();
  (void)m.machine.on(TrackingEvent::kStart);  // IDLE -> ALIGN
  m.summary.transitions.push_back({0, TrackingState::kIdle, TrackingState::kAlign, "operator start"});
  std::int64_t index = 0, start_ns = loop_start_ns;
  std::uint64_t allocations_at_warmup = 0;
  std::int64_t aligned_at = -1;
  // A couch does not start at zero (a run after another, a controller restarted where it
  // stopped): the loop's commands count from the target the actuator reports now.
  if (m.parts.actuator != nullptr) {
    drivers::ActuatorState now_at;
    if (m.parts.actuator->readback(&now_at, to_deadline(loop_start_ns + period)) == DeviceStatus::kOk &&
        !now_at.fault && now_at.target.allFinite()) {
      m.commanded_total = now_at.target;
      m.couch_position = now_at.position;
    }
  }
  m.parts.frames->request_exposure(start_ns);
  const char* ended = "cycle count reached";
  bool wait_for_writers = true;  // simulated clock: below
  for (std::int64_t executed = 0; m.settings.cycles <= 0 || executed < m.settings.cycles; ++executed) {
    if (stop_.load(std::memory_order_relaxed)) {
      ended = "stop requested";
      break;
    }
    // On the simulated clock cycles follow each other without the period between them in
    // which, on the real one, the journal's and the archive's writers catch up. The cycle waits
    // for them instead: a disk that failed is seen at this cycle's gate, and no pair is dropped
    // for want of a slot, whatever the writer threads' scheduling. A writer stuck on its disk for
    // 10 s ends the waiting for the rest of the run (the queues then absorb it, as on the real
    // clock), so a stalled disk slows a simulation once, not every cycle.
    if (clock.back_to_back() && wait_for_writers) {
      constexpr std::chrono::seconds kWriterWait{10};
      wait_for_writers = (m.parts.journal == nullptr || m.parts.journal->wait_taken(kWriterWait)) &&
                         (m.parts.archive == nullptr || m.parts.archive->wait_for_slot(kWriterWait));
    }
    // The cycle's own work starts now; acquire may move it (CycleClock::work_started_ns).
    m.cycle_wall_start_ns = monotonic_now_ns();
    if (aligned_at >= 0 && executed == aligned_at + m.settings.warmup_cycles &&
        m.parts.allocation_count != nullptr)
      allocations_at_warmup = m.parts.allocation_count();
    JournalRecord record;
    const bool go_on = m.cycle(index, start_ns, &record);
    if (m.ended_by_source != nullptr) break;  // no pair: not a cycle
    if (aligned_at < 0 && m.summary.aligned) aligned_at = executed;
    const std::int64_t wall_end = monotonic_now_ns();
    // A cycle that ran in ALIGN (a cold registration, which may run past its period), also one
    // that a resume or reset took there from HOLD or FAULT.
    const bool was_align = m.cycle_state.aligning;
    if (!was_align) m.cycle_ms.add(ms_between(m.cycle_wall_start_ns, wall_end));
    ++m.summary.cycles;
    m.summary.operator_refused += record.operator_refused;
    for (std::size_t i = 0; i < m.summary.operator_refused_by_reason.size(); ++i)
      m.summary.operator_refused_by_reason[i] += record.operator_refused_by_reason[i];
    // The next cycle: on the simulated clock the next period (unless a stall was injected); on
    // the host's the next period start not yet past (an overrun skips the periods it ran into).
    const NextCycle next = clock.next(loop_start_ns, period, index, start_ns, wall_end);
    if (next.overrun && !was_align) {
      ++m.summary.overruns;
      m.summary.skipped_periods += next.skipped;
    }
    m.consecutive_overruns = next.overrun && !was_align ? m.consecutive_overruns + 1 : 0;
    record.overrun = next.overrun ? 1 : 0;
    record.skipped_periods = static_cast<std::uint32_t>(next.skipped);
    if (m.parts.observer != nullptr) m.parts.observer->on_cycle(record);
    if (m.parts.feed != nullptr) m.publish_to_feed(record);
    if (m.parts.journal != nullptr) m.parts.journal->append(record);
    if (m.settings.status_line) m.write_status_line(index, record);
    if (!go_on) break;
    index = next.index;
    start_ns = next.start_ns;
    m.plan_next_exposure(start_ns);
    clock.wait_until(start_ns);
  }
  const std::uint64_t allocations_at_end =
      m.parts.allocation_count != nullptr ? m.parts.allocation_count() : 0;
  m.summary.ended = m.ended_by_operator != nullptr ? m.ended_by_operator
                    : m.ended_by_source != nullptr ? m.ended_by_source
                                                   : ended;
  m.hold_actuator(monotonic_now_ns() + period);
  if (m.parts.actuator != nullptr) m.parts.actuator->set_beam_permit(false);
  if (m.settings.status_line) (void)!::write(STDERR_FILENO, "\n", 1);

  m.finish_summary(aligned_at, allocations_at_warmup, allocations_at_end);
  return m.summary;
}

}  // namespace lftrack::loop
