#include "lftrack/host/tracking_loop.hpp"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>

#include "lftrack/host/cycle_schedule.hpp"

namespace lftrack::host {

using drivers::DeviceStatus;
using tracking::Pose;
using tracking::PoseDelta;
using tracking::Vector6d;

namespace {

constexpr std::size_t kMaxTransitions = 256;

drivers::Deadline to_deadline(std::int64_t ns) {
  return drivers::Deadline(
      std::chrono::duration_cast<drivers::Deadline::duration>(std::chrono::nanoseconds(ns)));
}

double ms_between(std::int64_t a_ns, std::int64_t b_ns) {
  return 1e-6 * static_cast<double>(b_ns - a_ns);
}

// A(d): the rigid motion of delta d about the origin, as a pose.
Pose motion_of(const Vector6d& d, const Eigen::Vector3d& origin) {
  return tracking::apply_delta(Pose::Identity(), PoseDelta::from_vector(d), origin);
}

// The gate's reason for a registration the verdict rejected.
GateReason gate_reason_of(VerdictReason r) {
  switch (r) {
    case VerdictReason::kLowSimilarity:
      return GateReason::kLowSimilarity;
    case VerdictReason::kViewsDisagree:
      return GateReason::kViewsDisagree;
    case VerdictReason::kOutsideEnvelope:
      return GateReason::kOutsideEnvelope;
    case VerdictReason::kImageQuality:
      return GateReason::kImageQuality;
    default:
      return GateReason::kNoResult;
  }
}

}  // namespace

struct TrackingLoop::Impl {
  LoopParts parts;
  LoopSettings settings;
  tracking::PreparedPlan align_plan, track_plan;
  std::int64_t period_ns = 0;
  Eigen::Vector3d origin_room = Eigen::Vector3d::Zero();
  Pose nominal = Pose::Identity();

  // Buffers of the cycle.
  drivers::FramePair pair;
  std::vector<tracking::Image<float>> line_integral;
  std::vector<tracking::Image<unsigned char>> valid;
  std::vector<tracking::ImageView<const float>> frame_views;
  std::vector<tracking::ImageView<const unsigned char>> mask_views;
  std::vector<tracking::Image<float>> check_drr;             // per view: the DRR at the result
  std::vector<tracking::Image<unsigned char>> check_valid;   // and its valid pixels
  tracking::RegistrationResult result;

  // Control state.
  TrackingStateMachine machine;
  MotionPredictor predictor{0, 1, 0};
  Pose last_registered = Pose::Identity();
  Vector6d couch_at_last_registration = Vector6d::Zero();
  bool have_registration = false;
  Vector6d commanded_total = Vector6d::Zero();  // what the actuator was last told, as travel
  tracking::FrameQualityIssue quality_issue = tracking::FrameQualityIssue::kOk;  // this cycle's frames
  int consecutive_overruns = 0;                // cycles in a row that overran, up to the last
  Vector6d aligned_couch = Vector6d::Zero();   // couch target after the set-up move
  Vector6d couch_position = Vector6d::Zero();  // last read-back
  std::array<double, kMaxGateViews> reference_similarity{};
  int consecutive_failures = 0;
  bool approve_next_step = false;
  std::int64_t cycles_in_state = 0;
  // The HOLD or FAULT the loop is in (0: neither) and the last id given; an operator's resume or
  // reset must answer the current one (operator_input.hpp).
  std::uint32_t hold_id = 0;
  std::mt19937 hold_id_random{std::random_device{}()};  // ids no command sent earlier can name
  std::uint32_t new_hold_id() {
    std::uniform_int_distribution<std::uint32_t> six_digits(100000, 999999);
    std::uint32_t id = six_digits(hold_id_random);
    while (id == last_hold_id) id = six_digits(hold_id_random);
    return last_hold_id = id;
  }
  std::uint32_t last_hold_id = 0;
  const char* state_reason = "operator start";  // why the loop entered its state (static text)
  OperatorCommand stop_sent_before_hold = OperatorCommand::kNone;  // taken by on_hold, acted on next cycle
  const char* ended_by_operator = nullptr;
  const char* ended_by_source = nullptr;

  // Statistics.
  Histogram cycle_ms{0.01, 2000}, registration_ms{0.01, 2000}, residual_mm{0.001, 100};
  Histogram acquire_ms{0.01, 2000}, preprocess_ms{0.01, 2000};  // the cycle's other stages
  double evaluations_sum = 0;
  LoopSummary summary;

  void transition(std::int64_t cycle, const StateTransition& t, TrackingEvent event, JournalRecord* record) {
    if (!t.changed()) return;
    record->event = static_cast<std::uint8_t>(1 + static_cast<int>(event));
    if (t.to == TrackingState::kHold) ++summary.holds;
    if (t.to == TrackingState::kFault) ++summary.faults;
    const bool stopped = t.to == TrackingState::kHold || t.to == TrackingState::kFault;
    hold_id = stopped ? new_hold_id() : 0;
    state_reason = t.reason;
    if (summary.transitions.size() < kMaxTransitions)
      summary.transitions.push_back({cycle, t.from, t.to, t.reason});
    cycles_in_state = 0;
  }

  void hold_actuator(std::int64_t deadline_ns) {
    if (parts.actuator == nullptr) return;
    parts.actuator->hold();
    drivers::ActuatorState state;
    if (parts.actuator->readback(&state, to_deadline(deadline_ns)) == DeviceStatus::kOk) {
      commanded_total = state.target;
      couch_position = state.position;
    }
  }

  // False, with quality_issue set, for a frame the image-quality gate refuses.
  bool preprocess() {
    for (std::size_t v = 0; v < pair.frames.size(); ++v) {
      const tracking::PixelWindow& w = parts.scene->roi_windows[v];
      quality_issue = tracking::assess_frame_quality(pair.frames[v].pixels.view(), w, parts.corrections[v],
                                                     settings.image_quality);
      if (quality_issue != tracking::FrameQualityIssue::kOk) return false;
      if (!tracking::preprocess_frame(pair.frames[v].pixels.view(), parts.corrections[v], w,
                                      line_integral[v].view(), valid[v].view())
               .ok())
        return false;
    }
    return parts.registration->set_frames(frame_views, mask_views).ok();
  }

  bool result_is_finite() const {
    if (!result.T_room_from_ct.matrix().allFinite()) return false;
    for (double s : result.view_similarity)
      if (!std::isfinite(s)) return false;
    return result.stop != tracking::OptimizerStop::kNonFinite;
  }

  OperatorView operator_view(std::int64_t index) const {
    OperatorView v;
    v.state = machine.state();
    v.hold_id = hold_id;
    v.cycle = index;
    v.cycles_in_state = cycles_in_state;
    v.hold_age_s = hold_id != 0 ? 1e-9 * double(period_ns) * double(cycles_in_state) : 0.0;
    v.reason = state_reason;
    return v;
  }

  // The loop has entered HOLD or FAULT this cycle: discard what the operator sent before it, and
  // say on stderr which id a resume or reset must name (the status line shows it on a terminal).
  void entered_hold(std::int64_t index, JournalRecord* r) {
    if (parts.operator_input != nullptr) {
      OperatorPoll before;
      before.refused = r->operator_refused;
      before.last_refusal = static_cast<OperatorRefusal>(r->operator_refusal);
      parts.operator_input->on_hold(operator_view(index), &before);
      if (before.command == OperatorCommand::kStop || before.command == OperatorCommand::kQuit)
        stop_sent_before_hold = before.command;
      r->operator_refused = before.refused;
      r->operator_refusal = static_cast<std::uint8_t>(before.last_refusal);
    }
    if (settings.status_line || !settings.announce_holds) return;
    char line[256];
    const bool fault = machine.state() == TrackingState::kFault;
    const int n = std::snprintf(line, sizeof line, "%s %u at cycle %lld: %s; %s with '%s %u'\n",
                                to_string(machine.state()), hold_id, static_cast<long long>(index), state_reason,
                                fault ? "reset" : "resume", fault ? "reset" : "resume", hold_id);
    if (n > 0) (void)!::write(STDERR_FILENO, line, std::min<std::size_t>(std::size_t(n), sizeof line - 1));
  }

  // One cycle; returns false when the loop should end (operator quit or stop).
  bool cycle(std::int64_t index, std::int64_t start_ns, JournalRecord* record);

  // Now on the loop's clock: the real one, or (simulated) the cycle's start plus the real time
  // spent in the cycle so far.
  std::int64_t now_ns(std::int64_t cycle_start_ns) const {
    const std::int64_t wall = monotonic_now_ns();
    return settings.simulated_clock ? cycle_start_ns + (wall - cycle_wall_start_ns) : wall;
  }
  std::int64_t cycle_wall_start_ns = 0;

  void write_status_line(std::int64_t index, const JournalRecord& r) const;
};

TrackingLoop::TrackingLoop(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
TrackingLoop::~TrackingLoop() {
  if (impl_ && impl_->parts.frames != nullptr) impl_->parts.frames->close();
}

Result<std::unique_ptr<TrackingLoop>> TrackingLoop::create(const LoopParts& parts,
                                                           const LoopSettings& settings) {
  if (parts.scene == nullptr || parts.registration == nullptr || parts.frames == nullptr)
    return invalid_argument("tracking loop: needs a scene, a registration and a frame source");
  const std::size_t views = parts.scene->scene.detectors.size();
  if (views == 0 || views > std::size_t(kMaxGateViews))
    return invalid_argument("tracking loop: 1 to 4 detectors");
  if (parts.corrections.size() != views)
    return invalid_argument("tracking loop: one detector correction per detector");
  if (!(settings.loop.period_ms > 0)) return invalid_argument("tracking loop: the period must be positive");
  auto impl = std::make_unique<Impl>();
  impl->parts = parts;
  impl->settings = settings;
  impl->period_ns = static_cast<std::int64_t>(std::llround(settings.loop.period_ms * 1e6));
  impl->origin_room = parts.scene->registration_origin_room_mm();
  impl->nominal = parts.scene->nominal_T_room_from_ct;
  auto align = tracking::registration_plan(settings.loop.align_plan);
  if (!align.ok()) return align.status();
  auto track = tracking::registration_plan(settings.loop.track_plan);
  if (!track.ok()) return track.status();
  auto align_prepared = parts.registration->prepare_plan(*align);
  if (!align_prepared.ok()) return align_prepared.status().with_context("align plan");
  auto track_prepared = parts.registration->prepare_plan(*track);
  if (!track_prepared.ok()) return track_prepared.status().with_context("track plan");
  impl->align_plan = std::move(align_prepared).value();
  impl->track_plan = std::move(track_prepared).value();
  const double lookahead =
      settings.loop.lookahead_s.value_or(1e-9 * double(impl->period_ns) + settings.actuator_latency_s);
  impl->predictor =
      MotionPredictor(settings.loop.prediction_cycles, settings.loop.prediction_order, lookahead);

  LFTRACK_RETURN_IF_ERROR(parts.frames->open(&impl->pair).with_context("frame source"));
  if (impl->pair.frames.size() != views)
    return failed_precondition("frame source: wrong number of detectors");
  for (std::size_t v = 0; v < views; ++v) {
    const tracking::PixelWindow& w = parts.scene->roi_windows[v];
    impl->line_integral.emplace_back(w.rows, w.cols);
    impl->valid.emplace_back(w.rows, w.cols);
    impl->check_drr.emplace_back(w.rows, w.cols);
    impl->check_valid.emplace_back(w.rows, w.cols);
  }
  for (std::size_t v = 0; v < views; ++v) {
    impl->frame_views.push_back(impl->line_integral[v].view());
    impl->mask_views.push_back(impl->valid[v].view());
  }
  impl->result.view_similarity.reserve(views);
  impl->summary.transitions.reserve(kMaxTransitions);
  return std::unique_ptr<TrackingLoop>(new TrackingLoop(std::move(impl)));
}

bool TrackingLoop::Impl::cycle(std::int64_t index, std::int64_t start_ns, JournalRecord* r) {
  const TrackingState state_before = machine.state();
  r->cycle = static_cast<std::uint64_t>(index);
  r->cycle_start_ns = start_ns;
  r->previous_state = static_cast<std::uint8_t>(state_before);
  const std::int64_t views = static_cast<std::int64_t>(pair.frames.size());
  quality_issue = tracking::FrameQualityIssue::kOk;

  // Operator first: a resume or stop acts on this cycle. Everything waiting is taken now and
  // judged against the state as it stands: nothing is kept for a later state.
  if (parts.operator_input != nullptr) {
    OperatorPoll polled;
    polled.accept(stop_sent_before_hold);
    stop_sent_before_hold = OperatorCommand::kNone;
    parts.operator_input->poll(operator_view(index), &polled);
    r->operator_refused = polled.refused;
    r->operator_refusal = static_cast<std::uint8_t>(polled.last_refusal);
    const OperatorCommand c = polled.command;
    if (c != OperatorCommand::kNone && c != OperatorCommand::kStatus)
      r->operator_command = static_cast<std::uint8_t>(1 + static_cast<int>(c));
    if (c == OperatorCommand::kQuit || c == OperatorCommand::kStop) {
      hold_actuator(start_ns + period_ns);
      transition(index, machine.on(TrackingEvent::kOperatorStop), TrackingEvent::kOperatorStop, r);
      r->state = static_cast<std::uint8_t>(machine.state());
      r->hold_id = hold_id;
      ended_by_operator = c == OperatorCommand::kQuit ? "operator quit" : "operator stop";
      return false;
    }
    if (c == OperatorCommand::kResume && state_before == TrackingState::kHold) {
      transition(index, machine.on(TrackingEvent::kOperatorResume), TrackingEvent::kOperatorResume, r);
      approve_next_step = true;  // the operator has seen the offset and accepts the move
      consecutive_failures = 0;
      predictor.reset();
    }
    if (c == OperatorCommand::kReset && state_before == TrackingState::kFault) {
      transition(index, machine.on(TrackingEvent::kOperatorReset), TrackingEvent::kOperatorReset, r);
      transition(index, machine.on(TrackingEvent::kStart), TrackingEvent::kStart, r);
      consecutive_failures = 0;
      predictor.reset();
    }
  }
  const TrackingState state = machine.state();
  const bool aligning = state == TrackingState::kAlign;

  // Acquire and preprocess.
  const std::int64_t acquire_started_ns = monotonic_now_ns();
  const DeviceStatus acquired = parts.frames->acquire(
      &pair, to_deadline(start_ns + std::int64_t(settings.loop.acquire_timeout_ms * 1e6)));
  const bool frames_ok = acquired == DeviceStatus::kOk;
  bool ok = frames_ok;
  if (!ok && parts.frames->exhausted()) {  // an archived sequence has ended
    ended_by_source = "end of the sequence";
    return false;
  }
  // On the simulated clock a frame arrives at its exposure time: waiting for the simulator's
  // renderer is not the loop's time.
  const std::int64_t acquired_ns = monotonic_now_ns();
  if (settings.simulated_clock) cycle_wall_start_ns = acquired_ns;
  if (!aligning) acquire_ms.add(ms_between(acquire_started_ns, acquired_ns));
  std::int64_t oldest_frame_ns = start_ns, newest_frame_ns = start_ns;
  if (ok) {
    oldest_frame_ns = newest_frame_ns = pair.frames[0].timestamp_ns;
    for (std::int64_t v = 0; v < views && v < 2; ++v) {
      r->frame_time_ns[v] = pair.frames[std::size_t(v)].timestamp_ns;
      r->frame_sequence[v] = pair.frames[std::size_t(v)].sequence;
    }
    for (const drivers::Frame& f : pair.frames) {
      oldest_frame_ns = std::min(oldest_frame_ns, f.timestamp_ns);
      newest_frame_ns = std::max(newest_frame_ns, f.timestamp_ns);
    }
    ok = preprocess();
    if (!aligning) preprocess_ms.add(ms_between(acquired_ns, monotonic_now_ns()));
  }

  // The truth at the frame time, before this cycle's command moves the simulated room on.
  if (parts.truth != nullptr) r->true_residual_mm = parts.truth->residual_mm();

  // Actuator read-back (where the couch is at the frame time, and whether it took our command).
  GateInput in;
  in.views = static_cast<int>(views);
  in.frames_ok = frames_ok;
  in.image_quality_ok = quality_issue == tracking::FrameQualityIssue::kOk;
  in.journal_ok = parts.journal == nullptr || !parts.journal->failed();
  in.consecutive_overruns = consecutive_overruns;
  if (parts.actuator != nullptr) {
    drivers::ActuatorState a;
    const DeviceStatus rb = parts.actuator->readback(&a, to_deadline(start_ns + period_ns));
    in.readback_valid = rb == DeviceStatus::kOk && !a.fault;
    if (in.readback_valid) {
      couch_position = a.position;
      const Vector6d error = a.target - commanded_total;
      in.readback_error_mm = error.head<3>().cwiseAbs().maxCoeff();
      in.readback_error_deg = tracking::rad_to_deg(error.tail<3>().cwiseAbs().maxCoeff());
      for (int i = 0; i < 6; ++i) r->readback[i] = a.position(i);
    }
  }
  if (ok && parts.archive != nullptr)
    parts.archive->append(index, pair, in.readback_valid ? &couch_position : nullptr);

  // Register: cold in ALIGN, warm from the last pose (moved with the couch) otherwise.
  if (ok &&
      (state == TrackingState::kAlign || state == TrackingState::kTrack || state == TrackingState::kHold)) {
    Pose start = nominal;
    if (!aligning && have_registration)
      start = tracking::apply_delta(
          last_registered, PoseDelta::from_vector(couch_position - couch_at_last_registration), origin_room);
    const double budget_ms = aligning ? 1e12 : settings.loop.registration_budget_ms;
    ok = parts.registration->run(start, aligning ? align_plan : track_plan, budget_ms, &result).ok() &&
         result_is_finite();
    // The verdict judges the alignment, whose result is the set-up move (no step limit). Tracking
    // cycles are judged by the gate's ratios against it: on a loaded host the verdict's absolute
    // floors skipped good time-boxed tracking registrations (closed-loop tests under ctest -j2).
    if (ok && settings.verdict && aligning) {
      VerdictInput judged;
      judged.views = static_cast<int>(views);
      judged.stop = result.stop;
      judged.pose_finite = result.T_room_from_ct.matrix().allFinite();
      for (std::int64_t v = 0; v < views && v < kMaxVerdictViews; ++v)
        judged.similarity[std::size_t(v)] = result.view_similarity[std::size_t(v)];
      judged.delta_from_nominal = tracking::delta_between(nominal, result.T_room_from_ct, origin_room).as_vector();
      // Each frame against the DRR at the result: what catches A/B-swapped detectors.
      if (parts.check_renderer != nullptr) {
        judged.has_check_ncc = true;
        for (std::int64_t v = 0; v < views && v < kMaxVerdictViews; ++v) {
          const std::size_t i = std::size_t(v);
          tracking::RenderExtras extras;
          extras.valid = check_valid[i].view();
          const bool rendered = parts.check_renderer
                                    ->render(result.T_room_from_ct, parts.scene->scene.detectors[i].view,
                                             parts.scene->roi_windows[i], check_drr[i].view(), &extras)
                                    .ok();
          judged.check_ncc[i] = rendered ? masked_ncc(line_integral[i].view(), valid[i].view(),
                                                      check_drr[i].view(), check_valid[i].view())
                                         : std::numeric_limits<double>::quiet_NaN();
        }
      }
      const RegistrationVerdict verdict = judge_registration(*settings.verdict, judged);
      if (!verdict.ok) {
        ok = false;
        in.registration_failure = gate_reason_of(verdict.reason);
      }
    }
    r->evaluations = static_cast<std::uint32_t>(result.evaluations);
    r->registration_ms = result.elapsed_ms;
    if (aligning) {
      summary.align_ms = result.elapsed_ms;
    } else {
      registration_ms.add(result.elapsed_ms);
      evaluations_sum += result.evaluations;
    }
  } else {
    ok = false;
  }
  in.registration_ok = ok;

  // The patient's own offset, its prediction, and the couch move that cancels it.
  Vector6d desired = commanded_total;
  if (ok) {
    const Vector6d registered =
        tracking::delta_between(nominal, result.T_room_from_ct, origin_room).as_vector();
    for (int i = 0; i < 6; ++i) r->pose_delta[i] = registered(i);
    for (std::int64_t v = 0; v < views && v < 4; ++v) {
      r->similarity[v] = result.view_similarity[std::size_t(v)];
      in.similarity[std::size_t(v)] = result.view_similarity[std::size_t(v)];
    }
    const Pose patient = motion_of(couch_position, origin_room).inverse() * result.T_room_from_ct;
    const Vector6d patient_offset = tracking::delta_between(nominal, patient, origin_room).as_vector();
    if (aligning) predictor.reset();
    predictor.add(1e-9 * double(newest_frame_ns), patient_offset);
    const Vector6d predicted = predictor.predict();
    desired =
        tracking::delta_between(motion_of(predicted, origin_room), Pose::Identity(), origin_room).as_vector();
    last_registered = result.T_room_from_ct;
    couch_at_last_registration = couch_position;
    have_registration = true;
  }
  if (aligning && ok) {
    for (std::int64_t v = 0; v < views; ++v)
      reference_similarity[std::size_t(v)] = in.similarity[std::size_t(v)];
    aligned_couch = desired;
  }
  in.reference_similarity = reference_similarity;
  in.step = desired - commanded_total;
  in.total = desired - aligned_couch;
  in.consecutive_failures = consecutive_failures;
  // Set-up and resumed moves are approved by the operator; in HOLD nothing moves, so only the
  // quality of the registration is judged (and counted towards FAULT).
  in.step_approved = aligning || approve_next_step || state == TrackingState::kHold;
  const std::int64_t decision_ns = now_ns(start_ns);
  in.frame_age_ms = ok ? ms_between(oldest_frame_ns, decision_ns) : 0.0;
  in.pair_skew_ms = ok ? ms_between(oldest_frame_ns, newest_frame_ns) : 0.0;

  // Gate, state, actuation.
  const GateOutput gate = evaluate_gate(settings.limits, in);
  consecutive_failures = gate.consecutive_failures;
  r->gate_decision = static_cast<std::uint8_t>(gate.decision);
  r->gate_reason = static_cast<std::uint8_t>(gate.reason);
  ++summary.decisions[std::size_t(gate.decision)];
  if (aligning) {
    const TrackingEvent e = gate.apply() ? TrackingEvent::kAligned : TrackingEvent::kAlignFailed;
    transition(index, machine.on(e), e, r);
    summary.aligned = summary.aligned || gate.apply();
  } else {
    transition(index, machine.on(TrackingEvent::kGate, gate), TrackingEvent::kGate, r);
  }
  const bool move = gate.apply() && (machine.state() == TrackingState::kTrack);
  if (move && parts.actuator == nullptr) {
    // Track and report: the correction is reported (the journal's pose), and taken as the new
    // reference, so the step limit judges the change from cycle to cycle.
    commanded_total = desired;
    approve_next_step = false;
  } else if (move && (in.step.array().abs() > 1e-9).any()) {
    const DeviceStatus sent = parts.actuator->command(in.step, to_deadline(start_ns + period_ns));
    if (sent == DeviceStatus::kOk) {
      commanded_total += in.step;
      for (int i = 0; i < 6; ++i) r->command[i] = in.step(i);
      r->command_sent = 1;
      ++summary.commands;
      approve_next_step = false;
    } else if (sent == DeviceStatus::kRefused) {
      // Nothing was sent or moved (the device knows of a fault): HOLD, as a read-back fault does.
      GateOutput refused;
      refused.decision = GateDecision::kHold;
      refused.reason = GateReason::kActuatorFault;
      r->gate_decision = static_cast<std::uint8_t>(refused.decision);
      r->gate_reason = static_cast<std::uint8_t>(refused.reason);
      transition(index, machine.on(TrackingEvent::kGate, refused), TrackingEvent::kGate, r);
    } else {  // it may have moved: stop safely (held below, with every other entry into HOLD or FAULT)
      transition(index, machine.on(TrackingEvent::kDeviceFault), TrackingEvent::kDeviceFault, r);
    }
  } else if (move) {
    approve_next_step = false;
  }
  if (machine.state() == TrackingState::kHold || machine.state() == TrackingState::kFault) {
    if (machine.state() != state) {  // entered this cycle
      hold_actuator(start_ns + period_ns);
      entered_hold(index, r);
    }
    predictor.reset();
  }
  r->hold_id = hold_id;
  r->beam_permit = machine.beam_permit() ? 1 : 0;
  if (parts.actuator != nullptr) parts.actuator->set_beam_permit(machine.beam_permit());
  r->state = static_cast<std::uint8_t>(machine.state());
  if (parts.truth != nullptr && machine.state() == TrackingState::kTrack)
    residual_mm.add(r->true_residual_mm);
  ++summary.states[std::size_t(machine.state())];
  ++cycles_in_state;
  return true;
}

void TrackingLoop::Impl::write_status_line(std::int64_t index, const JournalRecord& r) const {
  char line[256];
  const double step_mm =
      std::sqrt(r.command[0] * r.command[0] + r.command[1] * r.command[1] + r.command[2] * r.command[2]);
  int n = std::snprintf(line, sizeof line, "\r%7lld %-5s %-5s reg %5.1f ms %4u ev  step %5.2f mm",
                        static_cast<long long>(index), to_string(static_cast<TrackingState>(r.state)),
                        to_string(static_cast<GateDecision>(r.gate_decision)), r.registration_ms,
                        r.evaluations, step_mm);
  if (r.true_residual_mm >= 0 && n > 0 && n < int(sizeof line))
    n += std::snprintf(line + n, sizeof line - std::size_t(n), "  residual %5.2f mm", r.true_residual_mm);
  if (n > 0 && n < int(sizeof line))
    n += std::snprintf(line + n, sizeof line - std::size_t(n), "  overruns %lld  ",
                       static_cast<long long>(summary.overruns));
  // The HOLD on screen is the one a key answers; keys typed before it appeared are discarded.
  const TrackingState state = static_cast<TrackingState>(r.state);
  if (r.hold_id != 0 && n > 0 && n < int(sizeof line))
    n += std::snprintf(line + n, sizeof line - std::size_t(n), "%s %u: %s  %s [s]top [q]uit ", to_string(state),
                       r.hold_id, state_reason, state == TrackingState::kFault ? "[x] reset" : "[r]esume");
  else if (n > 0 && n < int(sizeof line))
    n += std::snprintf(line + n, sizeof line - std::size_t(n), "[s]top [q]uit ");
  if (n > 0) (void)!::write(STDERR_FILENO, line, std::min<std::size_t>(std::size_t(n), sizeof line - 1));
}

Result<LoopSummary> TrackingLoop::run() {
  Impl& m = *impl_;
  const bool simulated = m.settings.simulated_clock;
  const std::int64_t period = m.period_ns;
  const std::int64_t loop_start_ns = monotonic_now_ns();
  (void)m.machine.on(TrackingEvent::kStart);  // IDLE -> ALIGN
  m.summary.transitions.push_back({0, TrackingState::kIdle, TrackingState::kAlign, "operator start"});
  std::int64_t index = 0, start_ns = loop_start_ns;
  std::uint64_t allocations_at_warmup = 0;
  std::int64_t aligned_at = -1;
  m.parts.frames->request_exposure(start_ns);
  const char* ended = "cycle count reached";
  for (std::int64_t executed = 0; m.settings.cycles <= 0 || executed < m.settings.cycles; ++executed) {
    if (stop_.load(std::memory_order_relaxed)) {
      ended = "stop requested";
      break;
    }
    std::int64_t wall_start = monotonic_now_ns();
    m.cycle_wall_start_ns = wall_start;
    if (aligned_at >= 0 && executed == aligned_at + m.settings.warmup_cycles &&
        m.parts.allocation_count != nullptr)
      allocations_at_warmup = m.parts.allocation_count();
    JournalRecord record;
    const bool go_on = m.cycle(index, start_ns, &record);
    if (m.ended_by_source != nullptr) break;  // no pair: not a cycle
    if (aligned_at < 0 && m.summary.aligned) aligned_at = executed;
    const std::int64_t wall_end = monotonic_now_ns();
    if (simulated) wall_start = m.cycle_wall_start_ns;  // the work after the frames arrived
    const bool was_align = record.previous_state == static_cast<std::uint8_t>(TrackingState::kAlign);
    if (!was_align) m.cycle_ms.add(ms_between(wall_start, wall_end));
    ++m.summary.cycles;
    m.summary.operator_refused += record.operator_refused;
    // The next cycle: on the simulated clock always the next period; on the real one the next
    // period start not yet past (an overrun skips the periods it ran into).
    NextCycle next;
    if (simulated) {
      next.index = index + 1;
      next.start_ns = loop_start_ns + next.index * period;
    } else {
      next = next_cycle(loop_start_ns, period, index, wall_end);
      if (next.overrun && !was_align) {
        ++m.summary.overruns;
        m.summary.skipped_periods += next.skipped;
      }
    }
    m.consecutive_overruns = next.overrun && !was_align ? m.consecutive_overruns + 1 : 0;
    record.overrun = next.overrun ? 1 : 0;
    record.skipped_periods = static_cast<std::uint32_t>(next.skipped);
    if (m.parts.journal != nullptr) m.parts.journal->append(record);
    if (m.settings.status_line) m.write_status_line(index, record);
    if (!go_on) break;
    index = next.index;
    start_ns = next.start_ns;
    m.parts.frames->request_exposure(start_ns);
    if (!simulated) sleep_until_ns(start_ns);
  }
  const std::uint64_t allocations_at_end =
      m.parts.allocation_count != nullptr ? m.parts.allocation_count() : 0;
  m.summary.ended = m.ended_by_operator != nullptr ? m.ended_by_operator
                    : m.ended_by_source != nullptr ? m.ended_by_source
                                                   : ended;
  m.hold_actuator(monotonic_now_ns() + period);
  if (m.settings.status_line) (void)!::write(STDERR_FILENO, "\n", 1);

  LoopSummary& s = m.summary;
  if (m.residual_mm.count() > 0) {
    s.residual_mean_mm = m.residual_mm.mean();
    s.residual_p95_mm = m.residual_mm.quantile(0.95);
    s.residual_max_mm = m.residual_mm.max();
  }
  s.cycle_p50_ms = m.cycle_ms.quantile(0.5);
  s.cycle_p95_ms = m.cycle_ms.quantile(0.95);
  s.cycle_p99_ms = m.cycle_ms.quantile(0.99);
  s.cycle_max_ms = m.cycle_ms.max();
  s.registration_p50_ms = m.registration_ms.quantile(0.5);
  s.registration_p95_ms = m.registration_ms.quantile(0.95);
  s.registration_max_ms = m.registration_ms.max();
  s.acquire_p95_ms = m.acquire_ms.quantile(0.95);
  s.acquire_max_ms = m.acquire_ms.max();
  s.preprocess_p95_ms = m.preprocess_ms.quantile(0.95);
  s.preprocess_max_ms = m.preprocess_ms.max();
  s.evaluations_mean =
      m.registration_ms.count() > 0 ? m.evaluations_sum / double(m.registration_ms.count()) : 0;
  if (m.parts.allocation_count != nullptr && aligned_at >= 0) {
    const std::int64_t counted = s.cycles - (aligned_at + m.settings.warmup_cycles);
    if (counted > 0) {
      s.allocation_cycles = counted;
      s.allocations_per_cycle = double(allocations_at_end - allocations_at_warmup) / double(counted);
    }
  }
  return s;
}

nlohmann::json to_json(const LoopSummary& s) {
  nlohmann::json j;
  j["cycles"] = s.cycles;
  auto opt = [](const std::optional<double>& v) { return v ? nlohmann::json(*v) : nlohmann::json(nullptr); };
  j["residual_mm"] = {
      {"mean", opt(s.residual_mean_mm)}, {"p95", opt(s.residual_p95_mm)}, {"max", opt(s.residual_max_mm)}};
  j["cycle_ms"] = {
      {"p50", s.cycle_p50_ms}, {"p95", s.cycle_p95_ms}, {"p99", s.cycle_p99_ms}, {"max", s.cycle_max_ms}};
  j["registration_ms"] = {
      {"p50", s.registration_p50_ms}, {"p95", s.registration_p95_ms}, {"max", s.registration_max_ms}};
  j["acquire_ms"] = {{"p95", s.acquire_p95_ms}, {"max", s.acquire_max_ms}};
  j["preprocess_ms"] = {{"p95", s.preprocess_p95_ms}, {"max", s.preprocess_max_ms}};
  j["evaluations_mean"] = s.evaluations_mean;
  j["overruns"] = s.overruns;
  j["skipped_periods"] = s.skipped_periods;
  j["holds"] = s.holds;
  j["faults"] = s.faults;
  j["commands"] = s.commands;
  j["operator_commands_refused"] = s.operator_refused;
  j["aligned"] = s.aligned;
  j["align_ms"] = s.align_ms;
  j["allocations_per_cycle"] = opt(s.allocations_per_cycle);
  j["allocation_cycles"] = s.allocation_cycles;
  nlohmann::json states;
  for (int i = 0; i < 5; ++i) states[to_string(static_cast<TrackingState>(i))] = s.states[std::size_t(i)];
  j["states"] = states;
  nlohmann::json decisions;
  for (int i = 0; i < 4; ++i)
    decisions[to_string(static_cast<GateDecision>(i))] = s.decisions[std::size_t(i)];
  j["gate"] = decisions;
  nlohmann::json transitions = nlohmann::json::array();
  for (const LoopTransition& t : s.transitions)
    transitions.push_back(
        {{"cycle", t.cycle}, {"from", to_string(t.from)}, {"to", to_string(t.to)}, {"reason", t.reason}});
  j["transitions"] = transitions;
  j["ended"] = s.ended;
  if (!s.journal_error.empty()) j["journal_error"] = s.journal_error;
  return j;
}

}  // namespace lftrack::host
