#include "lftrack/session/scene_registration.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

#include "lftrack/calib/marker_detection.hpp"
#include "lftrack/session/detector_calibration_file.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::session {

using loop::ViewAgreement;

using tracking::Image;
using tracking::ImageView;
using tracking::Pose;

Result<std::shared_ptr<const tracking::DrrRenderer>> make_scene_renderer(const PreparedScene& p,
                                                                         const std::string& name,
                                                                         const std::filesystem::path& lf_dir,
                                                                         tracking::ThreadPool* pool) {
  tracking::RendererOptions options;
  options.octree_pivot = p.scene.octree_pivot;
  if (name == "lightfield") {
    const std::filesystem::path dir = lf_dir.empty() ? default_light_field_dir(p.scene) : lf_dir;
    auto fields = load_or_build_light_fields(p, *p.mu, p.scene.light_field, dir, pool);
    if (!fields.ok()) return fields.status();
    options.light_fields = *fields;
  }
  auto renderer = tracking::make_renderer(name, p.mu, options);
  if (!renderer.ok()) return renderer.status();
  return std::shared_ptr<const tracking::DrrRenderer>(std::move(renderer).value());
}

namespace {

tracking::RegistrationSetup scene_registration_setup(const PreparedScene& p, const RegistrationSpec& spec,
                                                     int detector_binning) {
  tracking::RegistrationSetup setup;
  if (detector_binning > 1) {
    const auto levels = setup.levels;
    for (auto level : levels) {
      level.bin *= detector_binning;
      setup.levels.push_back(level);
    }
    setup.levels.push_back({0.0, detector_binning});
  }
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    setup.views.push_back({p.scene.detectors[i].view, p.roi_windows[i], {}});
    if (i < p.roi_masks.size()) setup.views.back().region = p.roi_masks[i];  // roi.mask
  }
  setup.origin_room_mm = p.registration_origin_room_mm();
  setup.roi_centre_ct_mm = p.roi_centre_ct_mm;
  setup.roi_size_mm = p.scene.roi.size_mm;
  setup.nominal_T_room_from_ct = p.nominal_T_room_from_ct;
  setup.similarity = spec.similarity;
  setup.similarity_options.histogram_bins = spec.histogram_bins;
  // Search within twice the envelope the light fields were planned for.
  setup.search_translation_mm = 2 * p.scene.envelope.translation_mm;
  setup.search_rotation_deg = 2 * p.scene.envelope.rotation_deg;
  return setup;
}

}  // namespace

Result<std::unique_ptr<tracking::Registration>> make_scene_registration(
    const PreparedScene& p, std::shared_ptr<const tracking::DrrRenderer> renderer,
    const RegistrationSpec& spec, tracking::ThreadPool* pool, int detector_binning) {
  if (detector_binning < 1 || detector_binning > 16)
    return out_of_range("detector binning must be in [1, 16]");
  return tracking::Registration::create(std::move(renderer), scene_registration_setup(p, spec, detector_binning),
                                        pool);
}

Result<std::unique_ptr<ViewAgreement>> make_scene_view_agreement(const PreparedScene& p,
                                                                 std::shared_ptr<const tracking::DrrRenderer> renderer,
                                                                 const RegistrationSpec& spec,
                                                                 const tracking::RegistrationPlan& plan,
                                                                 tracking::ThreadPool* pool) {
  const tracking::RegistrationSetup joint = scene_registration_setup(p, spec, 1);
  std::vector<ViewAgreement::View> views;
  for (const tracking::RegistrationView& view : joint.views) {
    tracking::RegistrationSetup alone = joint;
    alone.views = {view};
    auto registration = tracking::Registration::create(renderer, std::move(alone), pool);
    if (!registration.ok()) return registration.status().with_context("view " + view.view.name + " alone");
    views.push_back({std::move(registration).value(), view.view.source_mm});
  }
  return ViewAgreement::create(std::move(views), plan, joint.origin_room_mm);
}

std::vector<ImageView<const float>> SceneFrames::frames() const {
  std::vector<ImageView<const float>> v;
  for (const auto& im : line_integral) v.push_back(im.view());
  return v;
}
std::vector<ImageView<const unsigned char>> SceneFrames::masks() const {
  std::vector<ImageView<const unsigned char>> v;
  for (const auto& im : valid) v.push_back(im.view());
  return v;
}

Result<SceneFrames> preprocess_scene_frames(const PreparedScene& p,
                                            const std::vector<Image<std::uint16_t>>& raw,
                                            const tracking::DetectorCorrection& correction) {
  return preprocess_scene_frames(p, raw, std::vector<tracking::DetectorCorrection>(raw.size(), correction));
}

Result<SceneFrames> preprocess_scene_frames(const PreparedScene& p,
                                            const std::vector<Image<std::uint16_t>>& raw,
                                            const std::vector<tracking::DetectorCorrection>& corrections) {
  if (raw.size() != p.scene.detectors.size() || corrections.size() != raw.size())
    return invalid_argument("expected " + std::to_string(p.scene.detectors.size()) + " frames and corrections, got " +
                            std::to_string(raw.size()) + " and " + std::to_string(corrections.size()));
  SceneFrames out;
  for (std::size_t i = 0; i < raw.size(); ++i) {
    const auto& view = p.scene.detectors[i].view;
    if (raw[i].rows() != view.rows || raw[i].cols() != view.cols)
      return invalid_argument("frame of view " + view.name + " is " + std::to_string(raw[i].rows()) + " x " +
                              std::to_string(raw[i].cols()) + ", the detector " + std::to_string(view.rows) +
                              " x " + std::to_string(view.cols));
    const tracking::PixelWindow& w = p.roi_windows[i];
    out.line_integral.emplace_back(w.rows, w.cols);
    out.valid.emplace_back(w.rows, w.cols);
    LFTRACK_RETURN_IF_ERROR(tracking::preprocess_frame(raw[i].view(), corrections[i], w,
                                                       out.line_integral.back().view(),
                                                       out.valid.back().view())
                                .with_context("view " + view.name));
  }
  return out;
}

Result<std::vector<tracking::DetectorCorrection>> scene_detector_corrections(const PreparedScene& p, bool simulated) {
  std::vector<tracking::DetectorCorrection> corrections;
  for (const DetectorSpec& d : p.scene.detectors) {
    if (!d.calibration_file.empty()) {
      auto calibration = load_detector_calibration(d.calibration_file);
      if (!calibration.ok()) return calibration.status().with_context("detector " + d.view.name);
      if (calibration->rows != d.view.rows || calibration->cols != d.view.cols)
        return failed_precondition("detector " + d.view.name + ": its calibration " + d.calibration_file + " is for " +
                                   std::to_string(calibration->rows) + " x " + std::to_string(calibration->cols) +
                                   " pixels, the detector has " + std::to_string(d.view.rows) + " x " +
                                   std::to_string(d.view.cols));
      corrections.push_back(calib::to_detector_correction(*calibration));
      continue;
    }
    if (!simulated && !d.simulator_calibration && frames_from_device(d.frames))
      return failed_precondition("detector " + d.view.name + " (" + describe_frames(d.frames) +
                                 ") has no detector calibration: name one as detectors[].calibration "
                                 "(lftrack calibrate detector --dark DIR --flood DIR)");
    // The simulator's detector model: nominal levels, no dark or gain image.
    corrections.push_back(tracking::nominal_detector_correction(p.scene.detectors.front().bits,
                                                                p.exposure.open_field_fraction));
  }
  return corrections;
}

Result<LocatedFiducial> locate_fiducial(const PreparedScene& p, const SceneFrames& frames, const Pose& start,
                                        double gamma_per_mm, double search_radius_mm) {
  if (p.scene.fiducials.positions_ct_mm.empty()) return failed_precondition("the scene names no fiducials");
  if (p.scene.detectors.size() < 2) return failed_precondition("a fiducial needs two views to triangulate");
  const Eigen::Vector3d marker_ct = p.scene.fiducials.positions_ct_mm.front();
  LocatedFiducial out;
  for (std::size_t i = 0; i < 2; ++i) {
    const auto& view = p.scene.detectors[i].view;
    const tracking::PixelWindow& w = p.roi_windows[i];
    const auto expected = view.project(start * marker_ct);
    if (!expected) return invalid_argument("the fiducial projects behind the source of view " + view.name);
    const double magnification = view.source_to_detector_mm() / (start * marker_ct - view.source_mm).norm();
    const double pitch = 0.5 * (view.pitch_col_mm + view.pitch_row_mm);
    calib::MarkerSearch search;
    search.expected_px = *expected - Eigen::Vector2d(w.col0, w.row0);
    search.search_radius_px = search_radius_mm * magnification / pitch;
    search.marker_radius_px = std::max(1.0, p.scene.fiducials.radius_mm * magnification / pitch);
    auto found = calib::find_marker(frames.line_integral[i].view(), frames.valid[i].view(), search);
    if (!found.ok()) return found.status().with_context("view " + view.name);
    out.pixels.push_back(found->pixel + Eigen::Vector2d(w.col0, w.row0));
  }
  auto point =
      calib::triangulate(p.scene.detectors[0].view, out.pixels[0], p.scene.detectors[1].view, out.pixels[1]);
  if (!point.ok()) return point.status();
  out.term.marker_ct_mm = marker_ct;
  out.term.marker_room_mm = point->point_mm;
  out.term.gamma_per_mm = gamma_per_mm;
  out.gap_mm = point->gap_mm;
  return out;
}

Result<Pose> pose_from_nominal_delta(const PreparedScene& p, const std::vector<double>& d) {
  if (d.size() != 6) return invalid_argument("a pose is 6 numbers: tx ty tz [mm] rx ry rz [deg]");
  for (double v : d)
    if (!std::isfinite(v)) return invalid_argument("a pose must be finite");
  tracking::PoseDelta delta;
  delta.translation_mm = {d[0], d[1], d[2]};
  delta.rotation_rad = {tracking::deg_to_rad(d[3]), tracking::deg_to_rad(d[4]), tracking::deg_to_rad(d[5])};
  return tracking::apply_delta(p.nominal_T_room_from_ct, delta, p.registration_origin_room_mm());
}

std::vector<double> nominal_delta_of(const PreparedScene& p, const Pose& T) {
  const tracking::PoseDelta d =
      tracking::delta_between(p.nominal_T_room_from_ct, T, p.registration_origin_room_mm());
  return {d.translation_mm.x(),
          d.translation_mm.y(),
          d.translation_mm.z(),
          tracking::rad_to_deg(d.rotation_rad.x()),
          tracking::rad_to_deg(d.rotation_rad.y()),
          tracking::rad_to_deg(d.rotation_rad.z())};
}

Pose pose_at_tre(const PreparedScene& p, const Pose& gold, const tracking::Vector6d& direction,
                 double target_mm) {
  const Eigen::Vector3d origin = p.registration_origin_room_mm();
  auto at = [&](double s) {
    return tracking::apply_delta(gold, tracking::PoseDelta::from_vector(direction * s), origin);
  };
  double lo = 0, hi = 1;
  while (scene_tre(p, at(hi), gold).mean_mm < target_mm && hi < 1e4) hi *= 2;
  for (int i = 0; i < 50; ++i) {
    const double mid = 0.5 * (lo + hi);
    (scene_tre(p, at(mid), gold).mean_mm < target_mm ? lo : hi) = mid;
  }
  return at(0.5 * (lo + hi));
}

tracking::Tre scene_tre(const PreparedScene& p, const Pose& T, const Pose& gold) {
  tracking::TreBox box;
  box.centre_ct_mm = p.registration_origin_ct_mm;
  box.edge_mm = p.scene.registration.tre_box_mm;
  return tracking::target_registration_error(T, gold, p.ct->geometry, box);
}

}  // namespace lftrack::session
