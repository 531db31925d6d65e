// What a cycle leaves behind: its journal record (built from the CycleState alone), the
// statistics gathered from that record, the state transitions and HOLD ids, and the lines people
// read (the status line, the HOLD announcement).

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>

#include "loop_impl.hpp"

namespace lftrack::loop {

static_assert(std::size(JournalRecord{}.operator_refused_by_reason) == kOperatorRefusalCodes,
              "the journal keeps a count for every refusal code");

namespace {
constexpr std::size_t kMaxTransitions = 256;
}  // namespace

JournalRecord TrackingLoop::Impl::record_of(const CycleState& c) const {
  JournalRecord r;
  r.cycle = static_cast<std::uint64_t>(c.index);
  r.cycle_start_ns = c.start_ns;
  r.previous_state = static_cast<std::uint8_t>(c.state_before);
  r.operator_refused = c.operator_refusals.refused;
  r.operator_refusal = static_cast<std::uint8_t>(c.operator_refusals.last_refusal);
  r.operator_first_refusal = static_cast<std::uint8_t>(c.operator_refusals.first_refusal);
  std::copy(c.operator_refusals.by_reason.begin(), c.operator_refusals.by_reason.end(), r.operator_refused_by_reason);
  if (c.operator_command != OperatorCommand::kNone)
    r.operator_command = static_cast<std::uint8_t>(1 + static_cast<int>(c.operator_command));
  if (c.changed_state) r.event = static_cast<std::uint8_t>(1 + static_cast<int>(c.event));
  for (int v = 0; v < 2; ++v) {
    r.frame_time_ns[v] = c.frame_time_ns[v];
    r.frame_sequence[v] = c.frame_sequence[v];
  }
  r.true_residual_mm = c.true_residual_mm;
  if (c.true_residual_mm >= 0)
    for (int i = 0; i < 6; ++i) r.true_target_residual[i] = c.true_target_residual(i);
  if (c.have_readback)
    for (int i = 0; i < 6; ++i) r.readback[i] = c.readback(i);
  if (c.registration_ran) {
    r.evaluations = c.evaluations;
    r.registration_ms = c.registration_ms;
  }
  if (c.registered || c.model_predicted) {  // a model cycle's: the model's offset on the couch
    for (int i = 0; i < 6; ++i) r.pose_delta[i] = c.pose_delta(i);
    for (int v = 0; v < c.gate_input.views && v < 4; ++v) r.similarity[v] = c.gate_input.similarity[std::size_t(v)];
  }
  r.gate_decision = static_cast<std::uint8_t>(c.gate.decision);
  r.gate_reason = static_cast<std::uint8_t>(c.gate.reason);
  if (c.command_sent) {
    for (int i = 0; i < 6; ++i) r.command[i] = c.command(i);
    r.command_sent = 1;
    r.command_acked_ns = c.command_acked_ns;
  }
  if (clock->measures_latency() && c.frames_ok) {  // the latency chain (latency_chain.hpp)
    r.frames_arrived_ns = c.acquired_ns;
    r.preprocessed_ns = c.preprocessed_ns;
    r.registered_ns = c.registered_ns;
    r.gated_ns = c.gated_ns;
    r.command_written_ns = c.command_written_ns;
  }
  r.hold_id = c.hold_id;
  r.beam_permit = c.beam_permit ? 1 : 0;
  // Why an applied cycle that ends in TRACK has the beam off: the alignment's (the state machine
  // permits no beam as it aligns), or the gate's reason (tracking_states.cpp).
  if (c.gate.apply() && c.state_after == TrackingState::kTrack && !c.beam_permit)
    r.beam_withheld = static_cast<std::uint8_t>(c.aligning ? BeamWithheld::kAlignment : c.gate.beam_withheld);
  r.state = static_cast<std::uint8_t>(c.state_after);
  record_imaging(c, &r);
  return r;
}

// Imaging on demand: why the cycle took a pair or did not, and, with a model, the surrogate and the
// model as the cycle left it.
void TrackingLoop::Impl::record_imaging(const CycleState& c, JournalRecord* r) const {
  r->imaging = static_cast<std::uint8_t>(1 + static_cast<int>(c.imaging));
  if (!settings.loop.imaging.model_mode()) return;
  r->surrogate_fault = static_cast<std::uint8_t>(c.surrogate_fault);
  const bool checked_a_ready_model = c.model_checked && c.model_check != CorrelationModel::Check::kNotReady;
  if (c.model_checked) r->model_check = static_cast<std::uint8_t>(1 + static_cast<int>(c.model_check));
  if (checked_a_ready_model && std::isfinite(model.last_check_error_mm()))
    r->model_check_error_mm = model.last_check_error_mm();
  r->model_flags = static_cast<std::uint8_t>((model.ready() ? 1 : 0) | (c.offset_from_model ? 2 : 0));
  r->model_pairs = static_cast<std::uint32_t>(model.pairs());
  if (c.surrogate_read) {
    r->surrogate_time_ns = c.surrogate.t_ns;
    r->surrogate[0] = c.surrogate.amplitude;
    r->surrogate[1] = c.surrogate.rate_per_s;
    // The prediction the cycle used: in a pair cycle the one its pair checked (before the refit).
    if (checked_a_ready_model || model.ready()) {
      const Eigen::Vector3d at =
          checked_a_ready_model ? c.model_checked_prediction : model.predict(c.surrogate);
      for (int i = 0; i < 3; ++i) r->model_prediction_mm[i] = at(i);
    }
  }
  for (int i = 0; i < 3; ++i) r->model_fit_rms_mm[i] = model.fit_rms_mm()(i);
  for (int axis = 0; axis < 3; ++axis)
    for (int term = 0; term < CorrelationModel::kTerms; ++term)
      r->model_coefficients[axis * CorrelationModel::kTerms + term] = model.coefficients()(axis, term);
}

void TrackingLoop::Impl::gather_statistics(const JournalRecord& r, const CycleState& c) {
  // The cycle's other stages and the registration: tracking cycles only (ALIGN's cold
  // registration is reported on its own).
  if (!c.aligning) {
    acquire_ms.add(ms_between(c.acquire_started_ns, c.acquired_ns));
    if (parts.actuator != nullptr) readback_ms.add(c.readback_ms);
    if (c.frames_ok) preprocess_ms.add(ms_between(c.acquired_ns, c.preprocessed_ns));
    if (c.verdict_checked) verdict_check_ms.add(c.verdict_check_ms);
  }
  if (c.view_checked) {
    view_check_ms.add(c.view_check_ms);
    if (!c.registered) ++view_checks_refused;
  }
  if (c.view_check_out_of_time) ++view_checks_out_of_time;
  if (c.registration_ran) {
    if (c.aligning) {
      summary.align_ms = r.registration_ms;
    } else {
      registration_ms.add(r.registration_ms);
      evaluations_sum += r.evaluations;
    }
  }
  ++summary.decisions[r.gate_decision];
  // Every exposure requested: a pair that failed to arrive may still have exposed the patient.
  if (c.imaging != ImagingReason::kNone) ++summary.xray_pairs;
  if (c.imaging == ImagingReason::kOutsideFit || c.imaging == ImagingReason::kConfirmMiss ||
      c.imaging == ImagingReason::kModelStale)
    ++summary.early_pairs;
  if (c.model_predicted) ++summary.model_cycles;
  if (c.model_checked && c.model_check != CorrelationModel::Check::kNotReady) {
    ++summary.model_checks;
    if (c.model_check != CorrelationModel::Check::kAgrees) ++summary.model_misses;
    if (std::isfinite(model.last_check_error_mm())) model_check_mm.add(r.model_check_error_mm);
  }
  if (r.command_sent) ++summary.commands;
  const auto state = static_cast<TrackingState>(r.state);
  if (parts.truth != nullptr && state == TrackingState::kTrack) residual_mm.add(r.true_residual_mm);
  accuracy.add(r);
  latency_chain.add(r);
  ++summary.states[r.state];
}

void TrackingLoop::Impl::transition(CycleState& c, const StateTransition& t, TrackingEvent event) {
  if (!t.changed()) return;
  c.event = event;
  c.changed_state = true;
  if (t.to == TrackingState::kHold) ++summary.holds;
  if (t.to == TrackingState::kFault) ++summary.faults;
  const bool stopped = t.to == TrackingState::kHold || t.to == TrackingState::kFault;
  hold_id = stopped ? new_hold_id() : 0;
  state_reason = t.reason;
  if (summary.transitions.size() < kMaxTransitions) summary.transitions.push_back({c.index, t.from, t.to, t.reason});
  cycles_in_state = 0;
}

std::uint32_t TrackingLoop::Impl::new_hold_id() {
  std::uniform_int_distribution<std::uint32_t> six_digits(100000, 999999);
  std::uint32_t id = six_digits(hold_id_random);
  while (id == last_hold_id) id = six_digits(hold_id_random);
  return last_hold_id = id;
}

OperatorView TrackingLoop::Impl::operator_view(std::int64_t index) const {
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
void TrackingLoop::Impl::entered_hold(CycleState& c) {
  if (parts.operator_input != nullptr) {
    OperatorPoll before;
    static_cast<OperatorRefusals&>(before) = c.operator_refusals;
    parts.operator_input->on_hold(operator_view(c.index), &before);
    if (before.command == OperatorCommand::kStop || before.command == OperatorCommand::kQuit)
      stop_sent_before_hold = before.command;
    c.operator_refusals = before;
  }
  if (settings.status_line || !settings.announce_holds) return;
  char line[256];
  const bool fault = machine.state() == TrackingState::kFault;
  const int n = std::snprintf(line, sizeof line, "%s %u at cycle %lld: %s; %s with '%s %u'\n",
                              to_string(machine.state()), hold_id, static_cast<long long>(c.index), state_reason,
                              fault ? "reset" : "resume", fault ? "reset" : "resume", hold_id);
  if (n > 0) (void)!::write(STDERR_FILENO, line, std::min<std::size_t>(std::size_t(n), sizeof line - 1));
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

}  // namespace lftrack::loop
