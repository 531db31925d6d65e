#pragma once
// The daily QA in a room whose actuator is a device (a Modbus couch, a CAN robot): the known
// shifts are made by the room's own couch, and the loop runs on the real clock with the scene's
// devices (daily_qa.hpp). With simulated detectors this is the hardware-in-the-loop room
// (`lftrack serve couch|robot --room FILE` and sim.couch_link): the phantom moves with the couch.

#include <atomic>
#include <memory>
#include <string>

#include "daily_qa_runs.hpp"
#include "lftrack/drivers/frame_source.hpp"

namespace lftrack::qa {

// The couch moved by `shift` (mm, rad, the patient's pose change in the room frame) through the
// scene's actuator, opened for it alone (through the couch calibration where the scene names
// one): read back, commanded once, then read back until it stands within 0.05 mm and 0.05
// degree of where it was sent, or `timeout_s` has passed (an error that says where it stood and
// where it was sent). The actuator is closed after; the loop opens its own. Returns the position
// (its travel, as the read-back gives it) it stood at before. The couch's lock (actuator_lock.hpp)
// is held while it is open. When `*interrupted` is set (the operator's Ctrl-C) before it arrives,
// the couch is sent back to where it stood and waited for there, and the move fails saying so.
Result<tracking::Vector6d> move_couch_by(const session::PreparedScene& scene, const tracking::Vector6d& shift,
                                         double timeout_s, const std::atomic<bool>* interrupted);
// The couch sent back to `position` of its travel (as move_couch_by returned it), and waited for
// (an interruption does not stop it: this is where an interrupted QA leaves the couch).
Status move_couch_to(const session::PreparedScene& scene, const tracking::Vector6d& position,
                     double timeout_s);

// The time the couch is given for a shift: its travel at the scene's speeds, three times over,
// plus its latency and 5 s.
double couch_move_timeout_s(const session::Scene& scene, const tracking::Vector6d& shift);

// The frames of cycles [dark_from, dark_to) (the loop's cycle index, as its records count it) are
// taken from the wrapped source and thrown away: the loop sees no frame, as if the detectors went
// dark. Everything else is the wrapped source's. Works on any frame source (a device's too),
// unlike the simulator's own drop option. It learns the cycle as the loop's observer (set it as
// the session's hooks.observer; it passes each record on to `next`), and is given its source by
// the session's wrap_frames hook (wrap()).
class DarkenedFrames final : public drivers::FrameSource, public loop::CycleObserver {
 public:
  DarkenedFrames(std::int64_t dark_from, std::int64_t dark_to, loop::CycleObserver* next)
      : dark_from_(dark_from), dark_to_(dark_to), next_(next) {}
  drivers::FrameSource* wrap(drivers::FrameSource* inner) {
    inner_ = inner;
    return this;
  }
  Status open(drivers::FramePair* pair) override { return inner_->open(pair); }
  void request_exposure(std::int64_t exposure_time_ns) override {
    inner_->request_exposure(exposure_time_ns);
  }
  void no_exposure(std::int64_t cycle_time_ns) override { inner_->no_exposure(cycle_time_ns); }
  bool exposes_on_request() const override { return inner_->exposes_on_request(); }
  drivers::DeviceStatus acquire(drivers::FramePair* pair, drivers::Deadline deadline) override;
  bool exhausted() const override { return inner_->exhausted(); }
  bool live() const override { return inner_->live(); }
  drivers::DetectorIdentity identity(std::size_t detector) const override {
    return inner_->identity(detector);
  }
  void close() override { inner_->close(); }
  void on_cycle(const loop::JournalRecord& record) override;
  std::int64_t simulated_stall_ns(std::int64_t cycle) override {
    return next_ != nullptr ? next_->simulated_stall_ns(cycle) : 0;
  }

 private:
  drivers::FrameSource* inner_ = nullptr;
  std::int64_t dark_from_, dark_to_;
  loop::CycleObserver* next_;
  std::atomic<std::int64_t> cycle_{0};  // the cycle now running: the last record's + 1
};

}  // namespace lftrack::qa
