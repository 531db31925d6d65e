// The cycle's register stage (cycle_stages.cpp has the others): the registration, cold in ALIGN
// and warm in TRACK. The verdict that judges its result is the next stage (cycle_verdict.cpp).

#include "loop_impl.hpp"

namespace lftrack::loop {

using tracking::Pose;
using tracking::PoseDelta;

// Register: cold in ALIGN, warm from the last pose (moved with the couch) otherwise.
void TrackingLoop::Impl::register_pair(CycleState& c) {
  const bool tracked_state =
      c.state == TrackingState::kAlign || c.state == TrackingState::kTrack || c.state == TrackingState::kHold;
  if (!c.frames_usable || !tracked_state) return;
  Pose start = nominal;
  if (!c.aligning && have_registration)
    start = tracking::apply_delta(last_registered, PoseDelta::from_vector(couch_position - couch_at_last_registration),
                                  origin_room);
  // Imaging on demand: a pair a second after the last finds a breathing target elsewhere; the
  // correlation model's offset at the pair's surrogate, on the couch as it stands, is nearer.
  tracking::Vector6d model_patient_offset;
  if (!c.aligning && model_offset(c, &model_patient_offset))
    start = tracking::apply_delta(Pose::Identity(), PoseDelta::from_vector(couch_position), origin_room) *
            tracking::apply_delta(nominal, PoseDelta::from_vector(model_patient_offset), origin_room);
  // The budget is wall time, so on the simulated clock, whose runs must repeat bit for bit
  // whatever the host's load, a tracking registration is not cut short either: a search cut at a
  // load-dependent moment made two runs of one seed diverge (ClosedLoop.TwoRunsOfOneSeed...).
  const double budget_ms =
      c.aligning ? kUnlimitedStageMs : clock->stage_budget_ms(settings.loop.registration_budget_ms);
  const RegistrationStage stage = c.aligning ? RegistrationStage::kAlign : RegistrationStage::kTrack;
  c.registered = parts.registration->run(start, stage, budget_ms, &result).ok() && result_is_finite();
  c.registration_ran = true;
  c.evaluations = static_cast<std::uint32_t>(result.evaluations);
  c.registration_ms = result.elapsed_ms;
}

}  // namespace lftrack::loop
