#include "lftrack/sim_devices/couch_calibration_run.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "lftrack/calib/phantom_pose.hpp"
#include "lftrack/session/loop_session.hpp"
#include "lftrack/sim/phantom_images.hpp"
#include "lftrack/sim/simulated_room.hpp"

namespace lftrack::sim_devices {

using session::couch_mounting;
using session::PreparedScene;

using tracking::Vector6d;

std::vector<Vector6d> default_couch_moves() {
  std::vector<Vector6d> moves;
  for (int axis = 0; axis < 6; ++axis) {
    for (const double sign : {1.0, -1.0}) {
      Vector6d q = Vector6d::Zero();
      q(axis) = sign * (axis < 3 ? 10.0 : tracking::deg_to_rad(2.0));
      moves.push_back(q);
    }
  }
  return moves;
}

namespace {

drivers::Deadline deadline_at(std::int64_t t_ns) {
  return drivers::Deadline(std::chrono::nanoseconds(t_ns));
}

}  // namespace

Result<CouchCalibrationRun> run_simulated_couch_calibration(const PreparedScene& p,
                                                            const CouchCalibrationRunOptions& o) {
  if (p.scene.detectors.size() != 2)
    return invalid_argument("calibrate couch needs a scene with two detectors");
  if (p.scene.actuator.type != "virtual") {
    return invalid_argument("calibrate couch (simulated) needs a scene with `actuator: {type: virtual}`");
  }
  const std::vector<Vector6d> moves = o.moves.empty() ? default_couch_moves() : o.moves;
  const drivers::ActuatorDynamics& couch_spec = p.scene.actuator.dynamics;
  for (const Vector6d& q : moves) {
    if (!q.allFinite() || q.head<3>().cwiseAbs().maxCoeff() > couch_spec.range_mm ||
        tracking::rad_to_deg(q.tail<3>().cwiseAbs().maxCoeff()) > couch_spec.range_deg) {
      return out_of_range("a couch move lies outside the couch's range (+-" +
                          std::to_string(couch_spec.range_mm) + " mm, +-" +
                          std::to_string(couch_spec.range_deg) + " deg)");
    }
  }
  // The phantom lies on the couch at the isocentre; the room has no patient motion.
  sim::SimulatedRoomSpec spec;
  spec.nominal_T_room_from_ct = tracking::Pose::Identity();  // "ct" here is the phantom's frame
  spec.origin_room_mm = p.registration_origin_room_mm();
  spec.couch = couch_spec;
  if (p.scene.actuator.mounting) spec.couch_T_room_from_couch = couch_mounting(*p.scene.actuator.mounting, p);
  sim::SimulatedRoom room(spec);
  const std::array<tracking::XrayView, 2> views = {p.scene.detectors[0].view, p.scene.detectors[1].view};

  CouchCalibrationRun run;
  run.true_T_room_from_couch = room.T_room_from_couch();
  std::int64_t t_ns = 1'000'000'000;
  room.advance_to_ns(t_ns);
  drivers::Actuator& couch = room.couch_actuator();
  Vector6d commanded = Vector6d::Zero();
  Eigen::Isometry3d guess = Eigen::Isometry3d::Identity();
  const Eigen::Isometry3d ideal = [&] {
    Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
    x.translation() = spec.origin_room_mm;
    return x;
  }();
  tracking::Pose zero = tracking::Pose::Identity();
  for (std::size_t i = 0; i <= moves.size(); ++i) {
    const Vector6d target = i == 0 ? Vector6d::Zero() : moves[i - 1];
    if (i > 0) {
      const drivers::DeviceStatus sent = couch.command(target - commanded, deadline_at(t_ns + 10'000'000));
      if (sent != drivers::DeviceStatus::kOk)
        return failed_precondition("the couch refused a calibration move");
      commanded = target;
      // Let it arrive: 0.1 s steps of the simulated clock, at most 60 s.
      drivers::ActuatorState state;
      const std::int64_t give_up = t_ns + 60'000'000'000;
      do {
        t_ns += 100'000'000;
        room.advance_to_ns(t_ns);
        if (couch.readback(&state, deadline_at(t_ns + 10'000'000)) != drivers::DeviceStatus::kOk) {
          return failed_precondition("couch read-back failed during calibration");
        }
      } while ((state.moving || (state.position - target).norm() > 1e-9) && t_ns < give_up);
      if (t_ns >= give_up)
        return failed_precondition("the couch did not arrive at a calibration move in 60 s");
    }
    std::array<tracking::Image<float>, 2> images;
    const tracking::Pose truth = room.true_T_room_from_ct();
    for (std::size_t k = 0; k < 2; ++k) {
      sim::PhantomImageSpec image_spec;
      image_spec.photons_per_pixel = o.photons_per_pixel;
      image_spec.supersample = 3;
      image_spec.seed = o.seed * 100000 + i * 2 + k;
      auto image = sim::render_phantom_image(o.phantom, truth, views[k], image_spec);
      if (!image.ok()) return image.status();
      images[k] = std::move(*image);
    }
    // Guess: where the ideal couch would have put it.
    guess = calib::room_motion_of_couch(ideal, target);
    auto pose = calib::measure_phantom_pose(o.phantom, views, {images[0].view(), images[1].view()}, guess);
    if (!pose.ok()) return pose.status().with_context("move " + std::to_string(i));
    run.worst_fre_mm = std::max(run.worst_fre_mm, pose->fre_rms_mm);
    if (i == 0) {
      zero = pose->T_room_from_phantom;
    } else {
      run.observations.push_back({target, pose->T_room_from_phantom});
    }
    if (o.progress) o.progress(int(i) + 1, int(moves.size()) + 1);
  }
  auto solved = calib::solve_couch_calibration(zero, run.observations, spec.origin_room_mm,
                                               p.scene.registration.tre_box_mm, spec.origin_room_mm);
  if (!solved.ok()) return solved.status();
  run.calibration = *solved;
  run.rotation_error_deg =
      tracking::rad_to_deg(tracking::rotation_log(run.true_T_room_from_couch.linear().transpose() *
                                                  solved->T_room_from_couch.linear())
                               .norm());
  run.centre_error_mm =
      (run.true_T_room_from_couch.translation() - solved->T_room_from_couch.translation()).norm();
  return run;
}

}  // namespace lftrack::sim_devices
