#include "room_runs.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <memory>
#include <thread>

#include "lftrack/session/actuator_lock.hpp"
#include "lftrack/session/calibrated_couch.hpp"
#include "lftrack/session/scene_devices.hpp"

namespace lftrack::qa {
namespace {

using Clock = std::chrono::steady_clock;
using drivers::DeviceStatus;

constexpr double kArrivedMm = 0.05;
constexpr double kArrivedDeg = 0.05;
constexpr auto kPollInterval = std::chrono::milliseconds(20);

std::string six(const tracking::Vector6d& v) {
  return fmt::format("({:+.2f}, {:+.2f}, {:+.2f}) mm, ({:+.2f}, {:+.2f}, {:+.2f}) deg", v(0), v(1), v(2),
                     tracking::rad_to_deg(v(3)), tracking::rad_to_deg(v(4)), tracking::rad_to_deg(v(5)));
}

}  // namespace

double couch_move_timeout_s(const session::Scene& scene, const tracking::Vector6d& shift) {
  const drivers::ActuatorDynamics& c = scene.actuator.dynamics;
  const double travel_s =
      std::max(shift.head<3>().norm() / std::max(c.max_speed_mm_s, 1e-3),
               tracking::rad_to_deg(shift.tail<3>().norm()) / std::max(c.max_speed_deg_s, 1e-3));
  return 3 * travel_s + c.latency_s + 5;
}

namespace {

bool is_set(const std::atomic<bool>* flag) {
  return flag != nullptr && flag->load(std::memory_order_acquire);
}

// Opens the scene's couch (through its calibration where the scene names one, as the loop drives
// it: positions are the patient's, in the room's axes), reads it back, sends it to
// `target_of(its state)` and waits for it there. Returns the position it stood at before. An
// interruption (`*interrupted` set) sends it back to that position and waits for it there.
Result<tracking::Vector6d> move_couch(
    const session::PreparedScene& p,
    const std::function<tracking::Vector6d(const drivers::ActuatorState&)>& target_of,
    const std::string& what, double timeout_s, const std::atomic<bool>* interrupted) {
  auto lock = session::ActuatorLock::acquire(p.scene);  // shared with the QA that holds it
  if (!lock.ok()) return lock.status();
  auto spec = session::device_actuator_spec(p.scene);
  if (!spec.ok()) return spec.status();
  auto made = drivers::make_actuator(std::move(spec).value());
  if (!made.ok()) return made.status();
  std::unique_ptr<drivers::Actuator> device = std::move(made).value();
  std::unique_ptr<session::CalibratedCouch> calibrated;
  drivers::Actuator* couch = device.get();
  if (p.scene.actuator.calibration) {
    calibrated = std::make_unique<session::CalibratedCouch>(
        device.get(), session::couch_mounting(*p.scene.actuator.calibration, p),
        p.registration_origin_room_mm());
    couch = calibrated.get();
  }
  LFTRACK_RETURN_IF_ERROR(couch->open().with_context("the couch, for " + what));
  struct Closer {
    drivers::Actuator* a;
    ~Closer() { a->close(); }
  } closer{couch};
  const auto deadline_of_call = [] { return Clock::now() + std::chrono::seconds(1); };
  drivers::ActuatorState state;
  DeviceStatus got = DeviceStatus::kTimeout;
  // A driver that has just connected may answer its first read-backs late, or a reply left over
  // from an earlier client: a few tries.
  for (int attempt = 0; attempt < 5 && got != DeviceStatus::kOk; ++attempt)
    got = couch->readback(&state, deadline_of_call());
  if (got != DeviceStatus::kOk)
    return io_error(fmt::format("the couch's read-back before {}: {}", what, drivers::to_string(got)));
  if (state.fault) return io_error("the couch reports a fault before " + what);
  const tracking::Vector6d before = state.position;
  const tracking::Vector6d target = target_of(state);
  // The operator asked to stop before the move began: no new motion is started.
  if (is_set(interrupted))
    return failed_precondition(
        fmt::format("interrupted before {}: the couch was not moved; it stands at {}", what, six(before)));
  got = couch->command(target - state.target, deadline_of_call());
  if (got != DeviceStatus::kOk)
    return io_error(fmt::format("the couch refused {}: {}", what, drivers::to_string(got)));
  auto give_up =
      Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeout_s));
  tracking::Vector6d goal = target;
  bool returning = false;  // interrupted: on its way back to `before`
  while (true) {
    got = couch->readback(&state, deadline_of_call());
    if (got == DeviceStatus::kOk) {
      if (state.fault) return io_error("the couch reports a fault during " + what);
      const tracking::Vector6d off = state.position - goal;
      if (!state.moving && off.head<3>().norm() <= kArrivedMm &&
          tracking::rad_to_deg(off.tail<3>().cwiseAbs().maxCoeff()) <= kArrivedDeg) {
        if (!returning) return before;
        return failed_precondition(
            fmt::format("interrupted during {}: the couch is back at {} of its travel, where it stood", what,
                        six(before)));
      }
    }
    if (!returning && is_set(interrupted) && got == DeviceStatus::kOk) {
      // Sent back the way it came, and given the time that move needs.
      returning = couch->command(before - state.target, deadline_of_call()) == DeviceStatus::kOk;
      if (!returning)
        return failed_precondition(
            fmt::format("interrupted during {}: the couch could not be sent back to {}; see where it "
                        "stands",
                        what, six(before)));
      goal = before;
      give_up = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(
                                   couch_move_timeout_s(p.scene, target - before)));
    }
    if (Clock::now() > give_up && returning)
      return failed_precondition(
          fmt::format("interrupted during {}: the couch did not get back to {} in time; it stood at {}", what,
                      six(before), six(state.position)));
    if (Clock::now() > give_up) {
      // Not left on its way: sent back to where it stood before this move (not waited for).
      drivers::ActuatorState now;
      const bool read = couch->readback(&now, deadline_of_call()) == DeviceStatus::kOk;
      const bool sent_back =
          read && couch->command(before - now.target, deadline_of_call()) == DeviceStatus::kOk;
      return failed_precondition(fmt::format(
          "the couch did not make {} within {:.1f} s: it stood at {} of its travel, sent to {}{}; {}", what,
          timeout_s, six(state.position), six(target),
          got == DeviceStatus::kOk ? "" : std::string(" (read-back ") + drivers::to_string(got) + ")",
          sent_back ? "sent back to " + six(before)
                    : std::string("it could not be sent back: see where it stands")));
    }
    std::this_thread::sleep_for(kPollInterval);
  }
}

}  // namespace

Result<tracking::Vector6d> move_couch_by(const session::PreparedScene& p, const tracking::Vector6d& shift,
                                         double timeout_s, const std::atomic<bool>* interrupted) {
  return move_couch(
      p, [&](const drivers::ActuatorState& s) { return tracking::Vector6d(s.target + shift); },
      "the QA's shift " + six(shift), timeout_s, interrupted);
}

Status move_couch_to(const session::PreparedScene& p, const tracking::Vector6d& position, double timeout_s) {
  auto moved = move_couch(
      p, [&](const drivers::ActuatorState&) { return position; },
      "the return to " + six(position) + " of its travel", timeout_s, nullptr);
  return moved.ok() ? Status{} : moved.status();
}

drivers::DeviceStatus DarkenedFrames::acquire(drivers::FramePair* pair, drivers::Deadline deadline) {
  const std::int64_t cycle = cycle_.load(std::memory_order_acquire);
  const drivers::DeviceStatus got = inner_->acquire(pair, deadline);
  if (cycle >= dark_from_ && cycle < dark_to_ && got == DeviceStatus::kOk) return DeviceStatus::kTimeout;
  return got;
}

void DarkenedFrames::on_cycle(const loop::JournalRecord& record) {
  cycle_.store(static_cast<std::int64_t>(record.cycle) + 1, std::memory_order_release);
  if (next_ != nullptr) next_->on_cycle(record);
}

}  // namespace lftrack::qa
