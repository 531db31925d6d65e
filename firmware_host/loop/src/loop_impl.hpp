#pragma once
// The loop's state, private to lftrack::loop. TrackingLoop::Impl holds what lives across cycles
// (the parts, the buffers create() sized, the control state, the statistics); CycleState holds one
// cycle, filled stage by stage in the design's order (DESIGN.md, "One cycle"):
//
//   operator -> acquire -> preprocess -> register -> judge -> control -> gate -> actuate
//     -> advance -> settle -> record
//
// Two judgements, in that order: the verdict (judge) says whether the registration is one to act
// on, before control takes its result; the gate says whether the move is one to make.
//
// Each stage reads what the earlier ones left in the CycleState and writes its own part (judge,
// whose verdict may reject the registration, clears register's `registered`); none reaches back
// into an earlier stage's work. Within a cycle the state machine moves in two places only
// (the run's start is IDLE to ALIGN before the first): the operator's commands (inputs, first) and
// `advance`, which takes the cycle's one event from the gate's
// decision and what the actuator answered. record_of() builds the journal record from the CycleState
// alone, and the statistics are gathered from that record after the cycle.

#include <array>
#include <cstdint>
#include <random>
#include <vector>

#include "lftrack/loop/correlation_model.hpp"
#include "lftrack/loop/cycle_clock.hpp"
#include "lftrack/loop/histogram.hpp"
#include "lftrack/loop/imaging_on_demand.hpp"
#include "lftrack/loop/latency_chain.hpp"
#include "lftrack/loop/motion_predictor.hpp"
#include "lftrack/loop/tracking_accuracy.hpp"
#include "lftrack/loop/tracking_loop.hpp"

namespace lftrack::loop {

// One cycle. Every field starts at its default; a stage that does not run leaves its fields so.
struct CycleState {
  std::int64_t index = 0;
  std::int64_t start_ns = 0;  // the period's start on the loop's clock
  TrackingState state_before = TrackingState::kIdle;
  TrackingState state = TrackingState::kIdle;  // after the operator's command: what the cycle runs in
  bool aligning = false;

  // operator
  OperatorCommand operator_command = OperatorCommand::kNone;  // acted on (kNone: none)
  OperatorRefusals operator_refusals;  // commands refused or discarded this cycle, by reason
  TrackingEvent event{};  // the last transition this cycle
  bool changed_state = false;

  // imaging on demand (imaging_on_demand.hpp): whether this cycle takes a pair, and the surrogate
  ImagingReason imaging = ImagingReason::kEveryCycle;
  bool surrogate_read = false;  // a reading with its rate (model imaging)
  SurrogateSample surrogate;
  SurrogateFault surrogate_fault = SurrogateFault::kOk;

  // acquire (and the actuator's read-back at the frame time)
  bool frames_ok = false;
  std::int64_t acquire_started_ns = 0, acquired_ns = 0, preprocessed_ns = 0;  // wall clock
  double readback_ms = 0;  // the actuator's read-back alone
  std::int64_t oldest_frame_ns = 0, newest_frame_ns = 0;                       // loop clock
  std::int64_t frame_time_ns[2] = {0, 0};
  std::uint32_t frame_sequence[2] = {0, 0};
  double true_residual_mm = -1;
  tracking::Vector6d true_target_residual = tracking::Vector6d::Zero();
  bool have_readback = false;
  tracking::Vector6d readback = tracking::Vector6d::Zero();

  // preprocess
  bool frames_usable = false;  // every frame passed the image-quality gate and was preprocessed

  // register (and judge, which clears `registered` when the verdict rejects the result)
  bool registered = false;  // a finite result, not rejected by the verdict
  std::uint32_t evaluations = 0;
  double registration_ms = 0;
  bool registration_ran = false;

  // judge
  bool verdict_checked = false;  // the NCC check ran (a DRR per view at the result)
  double verdict_check_ms = 0;   // its wall time: render and compare, every view
  bool view_checked = false;     // each view was registered alone from the result, and judged
  bool view_check_out_of_time = false;  // a view check was due but did not fit in the cycle
  double view_check_ms = 0;      // its wall time (also when out of time)

  // control
  bool model_predicted = false;  // the correlation model gave the patient's offset (no pair)
  bool offset_from_model =
      false;  // the control took the model's offset (model_predicted, or a pair that refitted it)
  bool model_checked = false;  // this cycle's pair checked the model (model_check)
  CorrelationModel::Check model_check = CorrelationModel::Check::kNotReady;
  Eigen::Vector3d model_checked_prediction =
      Eigen::Vector3d::Zero();                                 // the model's, before the check refitted it
  tracking::Vector6d pose_delta = tracking::Vector6d::Zero();  // registered pose, from nominal
  tracking::Vector6d desired = tracking::Vector6d::Zero();     // couch target that cancels the prediction
  GateInput gate_input;

  // gate and actuate
  GateOutput gate;
  // What actuate did: no move (the gate did not APPLY, the loop is not in TRACK or ALIGN, no
  // actuator, nothing to send), or the actuator's answer to the step.
  bool move_tried = false;
  drivers::DeviceStatus move_answer = drivers::DeviceStatus::kOk;
  bool command_sent = false;
  tracking::Vector6d command = tracking::Vector6d::Zero();
  std::int64_t command_acked_ns = 0;  // loop clock (simulated: the command's deadline)
  // The latency chain's links after the frames' (acquired_ns, preprocessed_ns): wall clock, which
  // is the loop's on the real clock (the journal keeps them only there); 0: not reached.
  std::int64_t registered_ns = 0, gated_ns = 0, command_written_ns = 0;

  // after actuation
  std::uint32_t hold_id = 0;
  bool beam_permit = false;
  TrackingState state_after = TrackingState::kIdle;
};

struct TrackingLoop::Impl {
  LoopParts parts;
  LoopSettings settings;
  std::unique_ptr<CycleClock> clock;  // the host's or the simulated one (settings.simulated_clock)
  std::int64_t period_ns = 0;
  Eigen::Vector3d origin_room = Eigen::Vector3d::Zero();
  tracking::Pose nominal = tracking::Pose::Identity();

  // Buffers of the cycle, sized by create().
  drivers::FramePair pair;
  std::vector<tracking::Image<float>> line_integral;
  std::vector<tracking::Image<unsigned char>> valid;
  std::vector<tracking::ImageView<const float>> frame_views;
  std::vector<tracking::ImageView<const unsigned char>> mask_views;
  std::vector<tracking::FrameQualityIssue> view_issue;  // per view, this cycle's quality gate
  std::vector<char> view_preprocessed;                  // per view: passed the gate and preprocessed
  std::vector<tracking::Image<float>> check_drr;            // per view: the DRR at the result
  std::vector<tracking::Image<unsigned char>> check_valid;  // and its valid pixels
  tracking::RegistrationResult result;
  CycleState cycle_state;

  // Control state.
  TrackingStateMachine machine;
  MotionPredictor predictor{0, 1, 0};
  tracking::Pose last_registered = tracking::Pose::Identity();
  tracking::Vector6d couch_at_last_registration = tracking::Vector6d::Zero();
  bool have_registration = false;
  tracking::Vector6d commanded_total = tracking::Vector6d::Zero();  // what the actuator was last told, as travel
  // Since a hold or a failed read-back (a dropped link), until a valid read-back in HOLD or FAULT:
  // an actuator that comes back holds where it stands (a couch stopped mid-move has a new target),
  // so that read-back is the target, not a disagreement with the last command. The loop is held
  // meanwhile (a failed read-back holds); a resume before the target is known meets the usual
  // comparison (read_back), so no operator decision is taken on a target the loop had not read.
  bool target_unknown = false;
  tracking::FrameQualityIssue quality_issue = tracking::FrameQualityIssue::kOk;  // this cycle's frames
  int consecutive_overruns = 0;                          // cycles in a row that overran, up to the last
  tracking::Vector6d aligned_couch = tracking::Vector6d::Zero();   // couch target after the set-up move
  tracking::Vector6d couch_position = tracking::Vector6d::Zero();  // last read-back
  std::array<double, kMaxGateViews> reference_similarity{};
  int consecutive_failures = 0;
  // The start of the first TRACK cycle after the alignment, or since the beam was last on, that
  // kept it off (-1: none; the beam was on, or the loop is elsewhere): the gate's beam_off_s.
  std::int64_t beam_off_since_ns = -1;
  bool approve_next_step = false;
  std::int64_t cycles_in_state = 0;
  // The HOLD or FAULT the loop is in (0: neither) and the last id given; an operator's resume or
  // reset must answer the current one (operator_input.hpp).
  std::uint32_t hold_id = 0;
  std::uint32_t last_hold_id = 0;
  std::mt19937 hold_id_random{std::random_device{}()};  // ids no command sent earlier can name
  const char* state_reason = "operator start";           // why the loop entered its state (static text)
  OperatorCommand stop_sent_before_hold = OperatorCommand::kNone;  // taken by on_hold, acted on next cycle
  const char* ended_by_operator = nullptr;
  const char* ended_by_source = nullptr;
  std::int64_t cycle_wall_start_ns = 0;

  // Imaging on demand (imaging_on_demand.hpp; unused with every_cycle): the surrogate's readings
  // as the source hands them over, its stream and watch, the model, and what decides the next
  // cycle's pair. The patient's offset at the last registration gives a model cycle its rotation.
  std::array<drivers::SurrogateReading, 64> surrogate_readings{};
  SurrogateStream surrogate_stream;
  SurrogateMonitor surrogate_monitor{SurrogateLimits{}};
  CorrelationModel model{CorrelationModelSpec{}};
  ImagingState imaging_state;
  ImagingReason next_imaging_reason = ImagingReason::kEveryCycle;  // of the cycle requested next
  tracking::Vector6d last_patient_offset = tracking::Vector6d::Zero();

  // Statistics.
  Histogram cycle_ms{0.01, 2000}, registration_ms{0.01, 2000}, residual_mm{0.001, 100};
  Histogram acquire_ms{0.01, 2000}, preprocess_ms{0.01, 2000};  // the cycle's other stages
  Histogram readback_ms{0.001, 2000};  // the actuator's read-back (a protocol's round trip)
  Histogram verdict_check_ms{0.001, 2000};  // the verdict's NCC check in tracking cycles
  Histogram view_check_ms{0.001, 5000};     // the verdict's view check, alignments and tracking cycles
  Histogram model_check_mm{0.001, 1000};    // the correlation model's checks: prediction against registration
  std::int64_t view_checks_refused = 0, view_checks_out_of_time = 0;
  std::int64_t tracking_cycles_since_view_check = 0;
  bool view_check_due = false;  // set by an alignment and every Nth tracking cycle; cleared when one ran
  TrackingAccuracy accuracy;           // the target residual per axis, the command latency
  LatencyChain latency_chain;          // the command latency link by link (real clock)
  double evaluations_sum = 0;
  LoopSummary summary;

  // One cycle, stage by stage; false when the loop should end (operator quit or stop, or the
  // end of an archived sequence: ended_by_source).
  bool cycle(std::int64_t index, std::int64_t start_ns, JournalRecord* record);

  // The stages (cycle_stages.cpp; register_pair in cycle_registration.cpp, judge and check_views
  // in cycle_verdict.cpp), each on cycle_state.
  bool take_operator_command(CycleState& c);  // false: stop or quit
  void read_surrogate(CycleState& c);         // model imaging: the readings since the last cycle
  bool acquire(CycleState& c);                // false: an archived sequence has ended
  void without_pair(CycleState& c);           // a model cycle's acquire: the read-back alone
  void read_back(CycleState& c);              // the actuator's read-back and the simulated truth
  void preprocess(CycleState& c);
  void register_pair(CycleState& c);
  // The verdict on the registration: a rejected one is no longer `registered`, and is the gate's
  // registration failure with the verdict's reason.
  void judge(CycleState& c);
  // The verdict's view check on the accepted result in `judged` when it is due and fits
  // (LoopSettings::view_check_every); rejudges into `verdict`.
  void check_views(CycleState& c, VerdictInput& judged, RegistrationVerdict& verdict);
  void control(CycleState& c);
  // Model imaging, in control: the pair's patient offset checks the model (TRACK), or the model
  // gives a cycle without a pair its offset (false: it cannot).
  void check_model(CycleState& c, const tracking::Vector6d& patient_offset);
  bool model_offset(const CycleState& c, tracking::Vector6d* patient_offset) const;
  // After the cycle: whether the next one, at `start_ns`, takes a pair; requests its exposure or
  // tells the source it takes none.
  void plan_next_exposure(std::int64_t start_ns);
  // A cycle planned without a pair needs one after all: the loop is not in TRACK, or the model
  // cannot say at the cycle's surrogate.
  bool pair_needed_now(const CycleState& c) const;
  // A resume or reset: the relation the model held may have changed with whatever held the loop
  // (a marker that slid, a patient who moved), so the model is fitted anew from the next pairs, and
  // the surrogate's watch starts again (a jump stays until then).
  void restart_model();
  void gate(CycleState& c);                        // the decision on the cycle's inputs; moves nothing
  void actuate(CycleState& c);                     // an APPLY carried out: the step sent, the answer kept
  drivers::DeviceStatus send_step(CycleState& c);  // the command, if any: what the actuator answered
  void advance(CycleState& c);                     // the cycle's one event for the state machine
  void settle(CycleState& c);  // holds on entry into HOLD/FAULT, the beam permit, the state

  // The journal record of a cycle, from its state alone (cycle_record.cpp), and the statistics
  // gathered from that record.
  JournalRecord record_of(const CycleState& c) const;
  void record_imaging(const CycleState& c, JournalRecord* r) const;
  void gather_statistics(const JournalRecord& record, const CycleState& c);

  // Helpers the stages share.
  void transition(CycleState& c, const StateTransition& t, TrackingEvent event);
  void hold_actuator(std::int64_t deadline_ns);
  // Anything in a cycle threw: the actuator is held and the beam permit dropped, whatever else
  // fails on the way (noexcept: called in a catch block before the error propagates).
  void hold_after_exception() noexcept;
  std::uint32_t new_hold_id();
  OperatorView operator_view(std::int64_t index) const;
  void entered_hold(CycleState& c);
  bool result_is_finite() const;
  // The cycle's record, and its images when due, to the watchers' feed (parts.feed).
  void publish_to_feed(const JournalRecord& record);
  void write_status_line(std::int64_t index, const JournalRecord& r) const;
  void finish_summary(std::int64_t aligned_at, std::uint64_t allocations_at_warmup,
                      std::uint64_t allocations_at_end);
};

// Small conversions the loop's files share.
drivers::Deadline to_deadline(std::int64_t ns);
double ms_between(std::int64_t a_ns, std::int64_t b_ns);

}  // namespace lftrack::loop
