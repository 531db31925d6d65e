#pragma once
// What a TrackingLoop runs on (LoopParts: the devices, the registration, the journal, the
// archive, the operator) and how (LoopSettings). The session assembles both from a scene
// (loop_session.hpp); the loop sees only these, never the scene file or the simulator.

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <vector>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/drivers/surrogate_source.hpp"
#include "lftrack/loop/cycle_feed.hpp"
#include "lftrack/loop/frame_archive.hpp"
#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/loop_registration.hpp"
#include "lftrack/loop/loop_spec.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/loop/view_agreement.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/frame_quality.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/registration.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::loop {

// The room's geometry as the loop needs it, per detector in the frame source's order.
struct LoopGeometry {
  std::vector<tracking::XrayView> views;           // room frame
  std::vector<tracking::PixelWindow> roi_windows;  // the ROI's projection on each detector
  tracking::Pose nominal_T_room_from_ct = tracking::Pose::Identity();
  Eigen::Vector3d registration_origin_room_mm = Eigen::Vector3d::Zero();
};

// The simulated truth the loop journals beside its own estimate (simulation only): how far the
// patient's target is, after correction, from where it should be. Read once per cycle, at the
// frame time; must not allocate.
class SimulatedTruth {
 public:
  virtual ~SimulatedTruth() = default;
  virtual double residual_mm() const = 0;
  // The target's true offset at the registration origin, room frame (mm, then a rotation vector
  // in rad): JournalRecord::true_target_residual.
  virtual tracking::Vector6d target_residual() const = 0;
};

// Watches the loop from its own thread (the chaos soak's invariant checks; a monitor): called
// once per cycle, after the cycle's record is complete (overrun and skipped periods included)
// and before it is journaled. Must not block; should not allocate in the steady state.
class CycleObserver {
 public:
  virtual ~CycleObserver() = default;
  virtual void on_cycle(const JournalRecord& record) = 0;
  // Simulated clock only: an injected host stall, how much longer than its period cycle
  // `cycle` is taken to have lasted (ns). The loop then overruns and skips periods exactly as
  // on the real clock. 0 (the default): the cycle ends within its period.
  virtual std::int64_t simulated_stall_ns(std::int64_t cycle) {
    (void)cycle;
    return 0;
  }
};

// What the loop runs on. Owned by the caller; all must outlive the loop. Optional parts may be
// null: no actuator (track and report), no journal or archive, no operator, no truth (not a simulation),
// no allocation counter (allocations_per_cycle is then not reported).
struct LoopParts {
  LoopGeometry geometry;
  LoopRegistration* registration = nullptr;  // the product's: PlannedRegistration
  drivers::FrameSource* frames = nullptr;
  std::vector<tracking::DetectorCorrection> corrections;  // per detector
  drivers::Actuator* actuator = nullptr;
  JournalWriter* journal = nullptr;
  FrameArchive* archive = nullptr;  // every acquired pair, numbered by cycle
  OperatorInput* operator_input = nullptr;
  const SimulatedTruth* truth = nullptr;
  // Renders the DRR at the alignment's result for the verdict's NCC check (the registration's
  // renderer); null: the check is not made.
  const tracking::DrrRenderer* check_renderer = nullptr;
  // The verdict's view check (each view registered alone, view_agreement.hpp); null: not made.
  ViewAgreement* view_agreement = nullptr;
  std::uint64_t (*allocation_count)() = nullptr;
  CycleObserver* observer = nullptr;
  // Watchers on other threads (the monitor page, OpenIGTLink): every record and, when due, the
  // images; sized by create(), published after each cycle, never waited for.
  CycleFeed* feed = nullptr;
  // The registration's pool, also for the views' preprocessing; null: one view after the other.
  tracking::ThreadPool* pool = nullptr;
  // The breathing surrogate (imaging_on_demand.hpp): needed with tracking.imaging model, unused
  // otherwise.
  drivers::SurrogateSource* surrogate = nullptr;
};

struct LoopSettings {
  LoopSpec loop;  // period, budgets, plans, prediction
  SafetyLimits limits;
  double actuator_latency_s = 0;  // for the default look-ahead
  std::int64_t cycles = 0;        // cycles to run (0: until quit or stop)
  bool simulated_clock = false;
  bool status_line = false;                    // one line per cycle on stderr (a terminal)
  bool announce_holds = false;                 // without a status line: a line on stderr per HOLD/FAULT
  int warmup_cycles = 5;                       // after ALIGN, before allocations are counted
  tracking::FrameQualityLimits image_quality;  // the image-quality gate's limits
  // The alignment's result is judged as `lftrack register` judges it (registration_verdict.hpp:
  // the measure's expected similarity, NCC against the DRR, per-view agreement, the pose
  // envelope); a rejected alignment is no result, with the verdict's reason: HOLD, nothing
  // moves. Unset: not judged.
  std::optional<VerdictLimits> verdict;
  // Tracking cycles judged too, as the alignment is (the NCC check included).
  bool judge_tracking = false;
  // With a view agreement: every alignment's result is checked (whatever it takes), and with
  // judge_tracking every Nth tracking cycle's (0: alignments only), within what is left of the
  // cycle on the real clock; a tracking check that does not fit is counted and tried again the
  // next cycle.
  int view_check_every = 0;
};

// The loop's period in integer nanoseconds, and the motion predictor's look-ahead (s): the scene's
// lookahead_s, or one period plus the actuator's latency.
std::int64_t loop_period_ns(const LoopSettings& s);
double prediction_lookahead_s(const LoopSettings& s);

}  // namespace lftrack::loop
