// The cycle's stages (loop_impl.hpp), in the order they run:
//   operator -> acquire -> preprocess -> register -> judge -> control -> gate -> actuate -> advance
//     -> settle.
// Each writes its part of the CycleState; the record and the statistics come after. The register
// stage is in cycle_registration.cpp, the judge stage (the verdict) in cycle_verdict.cpp.

#include <cmath>

#include "lftrack/loop/cycle_schedule.hpp"
#include "loop_impl.hpp"

namespace lftrack::loop {

using drivers::DeviceStatus;
using tracking::Pose;
using tracking::PoseDelta;
using tracking::Vector6d;

namespace {

// A(d): the rigid motion of delta d about the origin, as a pose.
Pose motion_of(const Vector6d& d, const Eigen::Vector3d& origin) {
  return tracking::apply_delta(Pose::Identity(), PoseDelta::from_vector(d), origin);
}

}  // namespace

// Operator first: a resume or stop acts on this cycle. Everything waiting is taken now and judged
// against the state as it stands: nothing is kept for a later state.
bool TrackingLoop::Impl::take_operator_command(CycleState& c) {
  if (parts.operator_input != nullptr) {
    OperatorPoll polled;
    polled.accept(stop_sent_before_hold);
    stop_sent_before_hold = OperatorCommand::kNone;
    parts.operator_input->poll(operator_view(c.index), &polled);
    c.operator_refusals = polled;
    const OperatorCommand command = polled.command;
    if (command != OperatorCommand::kNone && command != OperatorCommand::kStatus) c.operator_command = command;
    if (command == OperatorCommand::kQuit || command == OperatorCommand::kStop) {
      hold_actuator(c.start_ns + period_ns);
      transition(c, machine.on(TrackingEvent::kOperatorStop), TrackingEvent::kOperatorStop);
      ended_by_operator = command == OperatorCommand::kQuit ? "operator quit" : "operator stop";
      return false;
    }
    if (command == OperatorCommand::kResume && c.state_before == TrackingState::kHold) {
      transition(c, machine.on(TrackingEvent::kOperatorResume), TrackingEvent::kOperatorResume);
      approve_next_step = true;  // the operator has seen the offset and accepts the move
      consecutive_failures = 0;
      predictor.reset();
      restart_model();
    }
    if (command == OperatorCommand::kReset && c.state_before == TrackingState::kFault) {
      transition(c, machine.on(TrackingEvent::kOperatorReset), TrackingEvent::kOperatorReset);
      transition(c, machine.on(TrackingEvent::kStart), TrackingEvent::kStart);
      consecutive_failures = 0;
      predictor.reset();
      restart_model();
    }
  }
  c.state = machine.state();
  c.aligning = c.state == TrackingState::kAlign;
  return true;
}

// The actuator's read-back at the frame time (where the couch is, and whether it took our
// command), and the simulated truth then.
void TrackingLoop::Impl::read_back(CycleState& c) {
  GateInput& in = c.gate_input;
  const std::int64_t started = monotonic_now_ns();
  if (parts.actuator != nullptr) {
    drivers::ActuatorState a;
    const DeviceStatus rb = parts.actuator->readback(&a, to_deadline(c.start_ns + period_ns));
    // A read-back with a non-finite number in it is no read-back: taking its position would
    // carry NaN into the patient's offset and the predictor's history (found by the chaos soak).
    in.readback_valid = rb == DeviceStatus::kOk && !a.fault && a.position.allFinite() && a.target.allFinite();
    if (in.readback_valid) {
      couch_position = a.position;
      // Held where it stood when the link came back: the target, while the loop is held. In a
      // cycle that an operator's resume or reset has just taken out of HOLD or FAULT, the target
      // is compared as always: the operator decided without it, so a moved one holds again, and
      // that hold's read-back is the target for the next decision.
      if (target_unknown && (c.state == TrackingState::kHold || c.state == TrackingState::kFault)) {
        commanded_total = a.target;
        target_unknown = false;
      }
      const Vector6d error = a.target - commanded_total;
      in.readback_error_mm = error.head<3>().cwiseAbs().maxCoeff();
      in.readback_error_deg = tracking::rad_to_deg(error.tail<3>().cwiseAbs().maxCoeff());
      in.travel_left = a.target - a.position;  // still to go when the pair was exposed
      c.have_readback = true;
      c.readback = a.position;
    } else {
      target_unknown = true;
    }
  }
  c.readback_ms = ms_between(started, monotonic_now_ns());
  // The truth at the frame time, before this cycle's command moves the simulated room on.
  if (parts.truth != nullptr) {
    c.true_residual_mm = parts.truth->residual_mm();
    c.true_target_residual = parts.truth->target_residual();
  }
}

// The read-back, then the frame pair. The read-back comes first: the pair was exposed at the
// cycle's start, and devices that take their time to deliver it (a detector's readout and
// transfer) must not let a moving couch's read-back drift from it. A read-back recorded with the
// pair (replay) comes after it.
bool TrackingLoop::Impl::acquire(CycleState& c) {
  c.acquire_started_ns = monotonic_now_ns();
  GateInput& in = c.gate_input;
  const bool readback_after = parts.actuator != nullptr && parts.actuator->readback_follows_frames();
  if (!readback_after) read_back(c);
  const DeviceStatus acquired = parts.frames->acquire(
      &pair, to_deadline(c.start_ns + std::int64_t(settings.loop.acquire_timeout_ms * 1e6)));
  c.frames_ok = acquired == DeviceStatus::kOk;
  if (!c.frames_ok && parts.frames->exhausted()) {  // an archived sequence has ended
    ended_by_source = "end of the sequence";
    return false;
  }
  // On the simulated clock a frame arrives at its exposure time: waiting for the simulator's
  // renderer is not the loop's time.
  c.acquired_ns = monotonic_now_ns();
  cycle_wall_start_ns = clock->work_started_ns(cycle_wall_start_ns, c.acquired_ns);
  c.oldest_frame_ns = c.newest_frame_ns = c.start_ns;
  if (c.frames_ok) {
    c.oldest_frame_ns = c.newest_frame_ns = pair.frames[0].timestamp_ns;
    for (std::size_t v = 0; v < pair.frames.size() && v < 2; ++v) {
      c.frame_time_ns[v] = pair.frames[v].timestamp_ns;
      c.frame_sequence[v] = pair.frames[v].sequence;
    }
    for (const drivers::Frame& f : pair.frames) {
      c.oldest_frame_ns = std::min(c.oldest_frame_ns, f.timestamp_ns);
      c.newest_frame_ns = std::max(c.newest_frame_ns, f.timestamp_ns);
    }
  }
  if (readback_after) read_back(c);
  in.views = static_cast<int>(pair.frames.size());
  in.frames_ok = c.frames_ok;
  in.journal_ok = parts.journal == nullptr || !parts.journal->failed();
  in.consecutive_overruns = consecutive_overruns;
  return true;
}

// The image-quality gate, then each frame to line integrals in its ROI, the views side by side
// on the pool; the pair is archived when it passed. The gate reports the first view that fails.
void TrackingLoop::Impl::preprocess(CycleState& c) {
  quality_issue = tracking::FrameQualityIssue::kOk;
  c.frames_usable = false;
  if (c.frames_ok) {
    const int views = static_cast<int>(pair.frames.size());  // create() sized view_issue to match
    const auto one_view = [&](int begin, int end) {
      for (int v = begin; v < end; ++v) {
        const tracking::PixelWindow& w = parts.geometry.roi_windows[std::size_t(v)];
        const drivers::Frame& frame = pair.frames[std::size_t(v)];
        tracking::FrameQualityIssue& issue = view_issue[std::size_t(v)];
        issue = tracking::assess_frame_quality(frame.pixels.view(), w, parts.corrections[std::size_t(v)],
                                               settings.image_quality);
        view_preprocessed[std::size_t(v)] =
            issue == tracking::FrameQualityIssue::kOk &&
            tracking::preprocess_frame(frame.pixels.view(), parts.corrections[std::size_t(v)], w,
                                       line_integral[std::size_t(v)].view(), valid[std::size_t(v)].view())
                .ok();
      }
    };
    if (parts.pool != nullptr)
      parts.pool->parallel_for(views, 1, one_view);
    else
      one_view(0, views);
    c.frames_usable = true;
    for (int v = 0; v < views && c.frames_usable; ++v) {
      quality_issue = view_issue[std::size_t(v)];
      c.frames_usable = view_preprocessed[std::size_t(v)] != 0;
    }
    c.frames_usable = c.frames_usable && parts.registration->set_frames(frame_views, mask_views).ok();
  }
  c.gate_input.image_quality_ok = quality_issue == tracking::FrameQualityIssue::kOk;
  if (c.frames_usable && parts.archive != nullptr)
    parts.archive->append(c.index, pair, c.gate_input.readback_valid ? &couch_position : nullptr);
  c.preprocessed_ns = monotonic_now_ns();  // the archive's copy is this stage's, not the registration's
}

// The patient's own offset, its prediction, and the couch move that cancels it; everything the
// gate judges.
void TrackingLoop::Impl::control(CycleState& c) {
  GateInput& in = c.gate_input;
  c.desired = commanded_total;
  // The patient's own offset (set-up error and motion, without the couch): a registration's, or
  // in a cycle without a pair the correlation model's at the surrogate.
  Vector6d patient_offset = Vector6d::Zero();
  if (c.registered) {
    c.pose_delta = tracking::delta_between(nominal, result.T_room_from_ct, origin_room).as_vector();
    for (int v = 0; v < in.views && v < kMaxGateViews; ++v)
      in.similarity[std::size_t(v)] = result.view_similarity[std::size_t(v)];
    const Pose patient = motion_of(couch_position, origin_room).inverse() * result.T_room_from_ct;
    patient_offset = tracking::delta_between(nominal, patient, origin_room).as_vector();
    // The frames' age and skew now, so that the model takes only a pair the gate will accept.
    const std::int64_t checked_ns = clock->now_ns(c.start_ns);
    in.frame_age_ms = ms_between(c.oldest_frame_ns, checked_ns);
    in.pair_skew_ms = ms_between(c.oldest_frame_ns, c.newest_frame_ns);
    in.reference_similarity = reference_similarity;
    if (!c.aligning && result_quality(settings.limits, in) == GateReason::kOk) check_model(c, patient_offset);
    // With a ready model the correction follows the model, refitted by the pair: a control that took
    // the registrations at pairs and the model in between would jump by their difference at every
    // pair, which the predictor's extrapolation multiplies past the step limit. After a miss the
    // refitted model is followed with the beam off until a pair agrees with it again (the next
    // cycle's), or the second miss holds.
    Vector6d refitted;
    if (c.model_checked && c.model_check != CorrelationModel::Check::kNotReady &&
        model_offset(c, &refitted)) {
      patient_offset = refitted;
      c.offset_from_model = true;
    }
  } else if (in.model_cycle && model_offset(c, &patient_offset)) {
    c.model_predicted = c.offset_from_model = true;
    const Pose patient = tracking::apply_delta(nominal, PoseDelta::from_vector(patient_offset), origin_room);
    c.pose_delta =
        tracking::delta_between(nominal, motion_of(couch_position, origin_room) * patient, origin_room)
            .as_vector();
  }
  in.registration_ok = c.registered || c.model_predicted;
  if (in.registration_ok) {
    in.offset_from_plan = c.pose_delta;
    if (c.aligning) predictor.reset();
    predictor.add(c.newest_frame_ns, patient_offset);
    const Vector6d predicted = predictor.predict();
    c.desired = tracking::delta_between(motion_of(predicted, origin_room), Pose::Identity(), origin_room).as_vector();
  }
  if (c.registered) {
    last_registered = result.T_room_from_ct;
    couch_at_last_registration = couch_position;
    have_registration = true;
    if (c.aligning) {
      reference_similarity = in.similarity;
      aligned_couch = c.desired;
    }
  }
  in.reference_similarity = reference_similarity;
  in.model_unconfirmed =
      settings.loop.imaging.model_mode() && c.offset_from_model && imaging_state.miss_pending;
  in.step = c.desired - commanded_total;
  in.total = c.desired - aligned_couch;
  in.consecutive_failures = consecutive_failures;
  in.beam_off_s = beam_off_since_ns < 0 ? 0.0 : 1e-9 * static_cast<double>(c.start_ns - beam_off_since_ns);
  // Set-up and resumed moves are approved by the operator; in HOLD nothing moves, so only the
  // quality of the registration is judged (and counted towards FAULT).
  in.step_approved = c.aligning || approve_next_step || c.state == TrackingState::kHold;
  const std::int64_t decision_ns = clock->now_ns(c.start_ns);
  in.frame_age_ms = in.registration_ok ? ms_between(c.oldest_frame_ns, decision_ns) : 0.0;
  in.pair_skew_ms = c.registered ? ms_between(c.oldest_frame_ns, c.newest_frame_ns) : 0.0;
}

// The pure gate decides on the cycle's inputs. Nothing moves here, not even the state machine:
// an APPLY must first be carried out (actuate), and what the actuator answers is part of the
// cycle's one event (advance).
void TrackingLoop::Impl::gate(CycleState& c) {
  c.gate = evaluate_gate(settings.limits, c.gate_input);
  consecutive_failures = c.gate.consecutive_failures;
}

// Only an APPLY in TRACK, or ALIGN's APPLY (the set-up move), moves. The state is the one the
// operator's commands left (the machine has not moved since).
void TrackingLoop::Impl::actuate(CycleState& c) {
  c.move_tried = c.gate.apply() && (c.aligning || machine.state() == TrackingState::kTrack);
  if (c.move_tried) c.move_answer = send_step(c);
}

// The cycle's one event, from the gate's decision and the actuator's answer:
// - a move that may have happened and was not acknowledged (time-out, fault): a device fault;
// - a move the actuator refused (it knows of a fault; nothing moved): the refusal is one more
//   input the gate judges, as it judges every other, and it holds (in ALIGN: the alignment
//   failed, and a resume aligns again);
// - ALIGN: the set-up move accepted is the alignment (ALIGN becomes TRACK only then: a loop that
//   counted itself aligned without it would make the whole set-up move later as a tracking
//   correction, with the beam on; the chaos soak found a refused set-up move doing so after a
//   resume); a skipped cycle (no pair yet: a device's first frames are often late; a registration
//   that failed once) stays in ALIGN, moving nothing; any other decision (the gate's HOLD after
//   hold_after_failures failures, counted as in TRACK) is the alignment's failure;
// - otherwise the gate's decision, which the state machine follows (in TRACK it also sets the
//   beam permit).
void TrackingLoop::Impl::advance(CycleState& c) {
  if (c.move_tried && c.move_answer != DeviceStatus::kOk && c.move_answer != DeviceStatus::kRefused) {
    transition(c, machine.on(TrackingEvent::kDeviceFault), TrackingEvent::kDeviceFault);
    return;
  }
  const bool refused = c.move_tried && c.move_answer == DeviceStatus::kRefused;
  if (refused) {
    c.gate_input.command_refused = true;
    c.gate = evaluate_gate(settings.limits, c.gate_input);
    consecutive_failures = c.gate.consecutive_failures;
  }
  if (c.aligning) {
    if (c.move_tried && !refused) {
      transition(c, machine.on(TrackingEvent::kAligned), TrackingEvent::kAligned);
      summary.aligned = true;
    } else if (refused || c.gate.decision != GateDecision::kSkip) {
      transition(c, machine.on(TrackingEvent::kAlignFailed, c.gate), TrackingEvent::kAlignFailed);
    }
    return;
  }
  transition(c, machine.on(TrackingEvent::kGate, c.gate), TrackingEvent::kGate);
}

// This cycle's step to the actuator; kOk without one (track and report) or with nothing to send.
DeviceStatus TrackingLoop::Impl::send_step(CycleState& c) {
  const Vector6d& step = c.gate_input.step;
  if (parts.actuator == nullptr) {
    // Track and report: the correction is reported (the journal's pose), and taken as the new
    // reference, so the step limit judges the change from cycle to cycle.
    commanded_total = c.desired;
    approve_next_step = false;
    return DeviceStatus::kOk;
  }
  if (!(step.array().abs() > 1e-9).any()) {
    approve_next_step = false;
    return DeviceStatus::kOk;
  }
  // The command is due by the end of the period; on the host's clock the alignment's cycle (a cold
  // registration that may run past its period, which is why ALIGN is not counted as an overrun)
  // gets one period from now for its set-up move (cycle_clock.hpp).
  const std::int64_t due_ns = clock->command_due_ns(c.start_ns, period_ns, c.aligning);
  c.command_written_ns = monotonic_now_ns();
  const DeviceStatus sent = parts.actuator->command(step, to_deadline(due_ns));
  if (sent == DeviceStatus::kOk) {
    commanded_total += step;
    // Recorded as sent only where it moves a patient (not the recorded read-backs of a replay).
    c.command_sent = parts.actuator->moves_patient();
    if (c.command_sent) {
      c.command = step;
      c.command_acked_ns = clock->acknowledged_ns(due_ns);
    }
    approve_next_step = false;
  }
  return sent;
}

// On entry into HOLD or FAULT the actuator is held and earlier operator commands discarded; the
// beam permit follows the state.
void TrackingLoop::Impl::settle(CycleState& c) {
  const TrackingState now = machine.state();
  if (now == TrackingState::kHold || now == TrackingState::kFault) {
    if (now != c.state) {  // entered this cycle
      hold_actuator(c.start_ns + period_ns);
      entered_hold(c);
    }
    predictor.reset();
  }
  c.hold_id = hold_id;
  const bool permitted = machine.beam_permit();
  // The beam-off clock runs while TRACK keeps the beam off, from the first cycle after the
  // alignment's (whose cold registration has no time limit on the real clock, and whose set-up
  // move goes out at its end); it stops with the beam on, and in HOLD or FAULT (the operator's
  // resume or reset approves the move anew).
  if (permitted || c.aligning || now != TrackingState::kTrack)
    beam_off_since_ns = -1;
  else if (beam_off_since_ns < 0)
    beam_off_since_ns = c.start_ns;
  // Frames that show no patient in the room now (a replay) permit no beam, whatever they show.
  c.beam_permit = permitted && parts.frames->live();
  if (parts.actuator != nullptr) parts.actuator->set_beam_permit(c.beam_permit);
  c.state_after = now;
}

}  // namespace lftrack::loop
