#include "room_runs.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <thread>

#include "lftrack/host/calibrated_couch.hpp"
#include "lftrack/host/scene_devices.hpp"

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

double couch_move_timeout_s(const host::Scene& scene, const tracking::Vector6d& shift) {
  const sim::VirtualCouchSpec& c = scene.actuator.couch;
  const double travel_s =
      std::max(shift.head<3>().norm() / std::max(c.max_speed_mm_s, 1e-3),
               tracking::rad_to_deg(shift.tail<3>().norm()) / std::max(c.max_speed_deg_s, 1e-3));
  return 3 * travel_s + c.latency_s + 5;
}

Status move_couch_by(const host::PreparedScene& p, const tracking::Vector6d& shift, double timeout_s) {
  auto spec = host::device_actuator_spec(p.scene);
  if (!spec.ok()) return spec.status();
  auto made = drivers::make_actuator(std::move(spec).value());
  if (!made.ok()) return made.status();
  std::unique_ptr<drivers::Actuator> device = std::move(made).value();
  // Through the couch's calibration where the scene names one, as the loop drives it: the shift
  // is the patient's, in the room's axes.
  std::unique_ptr<host::CalibratedCouch> calibrated;
  drivers::Actuator* couch = device.get();
  if (p.scene.actuator.calibration) {
    calibrated = std::make_unique<host::CalibratedCouch>(
        device.get(), host::couch_mounting(*p.scene.actuator.calibration, p),
        p.registration_origin_room_mm());
    couch = calibrated.get();
  }
  LFTRACK_RETURN_IF_ERROR(couch->open().with_context("the couch, to make the QA's shift"));
  struct Closer {
    drivers::Actuator* a;
    ~Closer() { a->close(); }
  } closer{couch};
  const auto deadline_of_call = [] { return Clock::now() + std::chrono::seconds(1); };
  drivers::ActuatorState state;
  DeviceStatus got = DeviceStatus::kTimeout;
  // A driver that has just connected may answer its first read-back late: three tries.
  for (int attempt = 0; attempt < 3 && got != DeviceStatus::kOk; ++attempt)
    got = couch->readback(&state, deadline_of_call());
  if (got != DeviceStatus::kOk)
    return io_error(std::string("the couch's read-back before the QA's shift: ") + drivers::to_string(got));
  const tracking::Vector6d target = state.target + shift;
  got = couch->command(shift, deadline_of_call());
  if (got != DeviceStatus::kOk)
    return io_error(
        fmt::format("the couch refused the QA's shift {}: {}", six(shift), drivers::to_string(got)));
  const auto give_up =
      Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeout_s));
  while (true) {
    got = couch->readback(&state, deadline_of_call());
    if (got == DeviceStatus::kOk) {
      if (state.fault) return io_error("the couch reports a fault while making the QA's shift " + six(shift));
      const tracking::Vector6d off = state.position - target;
      if (!state.moving && off.head<3>().norm() <= kArrivedMm &&
          tracking::rad_to_deg(off.tail<3>().cwiseAbs().maxCoeff()) <= kArrivedDeg)
        return {};
    }
    if (Clock::now() > give_up)
      return failed_precondition(fmt::format(
          "the couch did not make the QA's shift {} within {:.1f} s: it stands at {}{}", six(shift),
          timeout_s, six(state.position - (target - shift)),
          got == DeviceStatus::kOk ? "" : std::string(" (read-back ") + drivers::to_string(got) + ")"));
    std::this_thread::sleep_for(kPollInterval);
  }
}

drivers::DeviceStatus DarkenedFrames::acquire(drivers::FramePair* pair, drivers::Deadline deadline) {
  const std::int64_t exposure = exposure_++;
  const drivers::DeviceStatus got = inner_->acquire(pair, deadline);
  if (exposure >= dark_from_ && exposure < dark_to_ && got == DeviceStatus::kOk)
    return DeviceStatus::kTimeout;
  return got;
}

}  // namespace lftrack::qa
