#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <sstream>

#include "lftrack/phantom/implanted_markers.hpp"
#include "lftrack/phantom/spine_phantom.hpp"
#include "lftrack/session/phantom_cache.hpp"
#include "lftrack/session/roi_mask.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_exposure.hpp"
#include "lftrack/tracking/volume_io.hpp"

namespace lftrack::session {
namespace {

using Eigen::Vector3d;

// The detector pixels covered by the projection of the ROI box, clipped to the detector.
Result<tracking::PixelWindow> roi_window(const tracking::XrayView& view_room,
                                         const tracking::Pose& T_room_from_ct, const Vector3d& centre_ct,
                                         const Vector3d& size_mm) {
  double c_lo = 1e300, c_hi = -1e300, r_lo = 1e300, r_hi = -1e300;
  for (int corner = 0; corner < 8; ++corner) {
    const Vector3d sign((corner & 1) ? 0.5 : -0.5, (corner & 2) ? 0.5 : -0.5, (corner & 4) ? 0.5 : -0.5);
    const auto px = view_room.project(T_room_from_ct * (centre_ct + sign.cwiseProduct(size_mm)));
    if (!px) return invalid_argument("the ROI reaches behind the source of view '" + view_room.name + "'");
    c_lo = std::min(c_lo, px->x());
    c_hi = std::max(c_hi, px->x());
    r_lo = std::min(r_lo, px->y());
    r_hi = std::max(r_hi, px->y());
  }
  const int col0 = std::max(0, static_cast<int>(std::floor(c_lo + 0.5)));
  const int row0 = std::max(0, static_cast<int>(std::floor(r_lo + 0.5)));
  const int col1 = std::min(view_room.cols, static_cast<int>(std::ceil(c_hi + 0.5)));
  const int row1 = std::min(view_room.rows, static_cast<int>(std::ceil(r_hi + 0.5)));
  if (col1 - col0 < 8 || row1 - row0 < 8) {
    return invalid_argument("the ROI projects onto fewer than 8 x 8 pixels of view '" + view_room.name +
                            "' (is it inside the field of view?)");
  }
  return tracking::PixelWindow{row0, col0, row1 - row0, col1 - col0};
}

}  // namespace

tracking::LightFieldPlanInput PreparedScene::light_field_plan(int index) const {
  tracking::LightFieldPlanInput in;
  in.view_room = scene.detectors[static_cast<std::size_t>(index)].view;
  in.roi_window = roi_windows[static_cast<std::size_t>(index)];
  in.nominal_T_room_from_ct = nominal_T_room_from_ct;
  in.registration_origin_room_mm = registration_origin_room_mm();
  in.roi_centre_ct_mm = roi_centre_ct_mm;
  in.envelope = scene.envelope;
  return in;
}

int PreparedScene::detector_index(const std::string& name) const {
  for (std::size_t i = 0; i < scene.detectors.size(); ++i)
    if (scene.detectors[i].view.name == name) return static_cast<int>(i);
  return -1;
}

// The ROI's centre must lie inside the CT (a target outside the scan tracks air); its box may
// reach past the CT's edge, which only crops it.
Status check_roi_inside_ct(const Scene& scene, const tracking::CtVolume& ct) {
  const Vector3d centre = *scene.roi.centre_ct_mm;
  const tracking::VolumeGeometry& g = ct.geometry;
  const Vector3d index = g.index_from_ct() * centre;
  bool inside = true;
  for (int a = 0; a < 3; ++a) inside = inside && index[a] >= -0.5 && index[a] <= double(g.size[a]) - 0.5;
  if (inside) return {};
  std::ostringstream m;
  m << scene.where("roi") << ": roi.centre_mm (" << centre.x() << ", " << centre.y() << ", " << centre.z()
    << ") mm lies outside the CT (" << tracking::describe(g) << "): the target must be in the scan";
  return invalid_argument(m.str());
}

// The registration origin must lie inside the ROI box: the pose is registered, and the envelope,
// the step limits and the TRE are measured, about it, while only what the ROI holds is seen. An
// origin outside it tracks a point the registration cannot see (issue 52: one 46 mm outside was
// accepted without a word).
Status check_origin_inside_roi(const PreparedScene& p) {
  const Vector3d offset = p.registration_origin_ct_mm - p.roi_centre_ct_mm;
  const Vector3d half = p.scene.roi.size_mm / 2;
  bool inside = true;
  for (int a = 0; a < 3; ++a) inside = inside && std::abs(offset[a]) <= half[a] * (1 + 1e-9);
  if (inside) return {};
  const Vector3d o = p.registration_origin_ct_mm, c = p.roi_centre_ct_mm;
  std::ostringstream m;
  m << p.scene.where("roi") << ": the registration origin (" << o.x() << ", " << o.y() << ", " << o.z()
    << ") mm lies outside the ROI box (centre (" << c.x() << ", " << c.y() << ", " << c.z() << ") mm, size "
    << p.scene.roi.size_mm.x() << " x " << p.scene.roi.size_mm.y() << " x " << p.scene.roi.size_mm.z()
    << " mm, CT frame): the registration would track a point it cannot see; move registration_origin_mm "
       "into the ROI or grow roi.size_mm";
  return invalid_argument(m.str());
}

Result<PreparedScene> prepare_scene(const Scene& scene, const std::string& ct_override,
                                    tracking::ThreadPool* pool) {
  PreparedScene out;
  out.scene = scene;
  if (!ct_override.empty()) out.scene.ct.path = ct_override;
  const auto t0 = std::chrono::steady_clock::now();
  std::optional<Vector3d> phantom_target;
  if (out.scene.ct.is_builtin_phantom()) {
    phantom::SpinePhantomOptions options;
    options.seed = out.scene.ct.phantom_seed;
    auto phantom = cached_spine_phantom(options, cache_dir_from_environment(), pool);
    if (!phantom.ok()) return phantom.status();
    phantom_target = phantom->vertebral_body_centres_mm[static_cast<std::size_t>(phantom->target_vertebra)];
    out.ct = std::make_shared<const tracking::CtVolume>(std::move(phantom->ct));
  } else {
    auto ct = tracking::read_ct(out.scene.ct.path);
    if (!ct.ok())
      return ct_override.empty() ? ct.status().with_context(out.scene.where("ct") + ": ct.path")
                                 : ct.status().with_context("--ct");
    out.ct = std::make_shared<const tracking::CtVolume>(std::move(ct).value());
  }
  spdlog::info("CT {}: {} ({:.1f} s)", out.scene.ct.path, tracking::describe(out.ct->geometry),
               std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  const FiducialSpec& fiducials = out.scene.fiducials;
  if (fiducials.insert) {
    auto with_markers = std::make_shared<tracking::CtVolume>(*out.ct);
    phantom::insert_markers(with_markers.get(), fiducials.positions_ct_mm, fiducials.radius_mm,
                            phantom::kMarkerHu);
    out.ct = std::move(with_markers);
  }
  out.mu = std::make_shared<const tracking::MuVolume>(
      tracking::to_attenuation(*out.ct, out.scene.ct.mu_water_per_mm));
  out.world_mu = out.mu;
  if (fiducials.insert) {
    auto world = std::make_shared<tracking::MuVolume>(*out.mu);
    phantom::insert_markers(world.get(), fiducials.positions_ct_mm, fiducials.radius_mm,
                            phantom::kSteelMuPerMm);
    out.world_mu = std::move(world);
  }

  // ROI centre: the scene's, else the phantom's target (posterior elements included), else the
  // volume centre (only reachable through --ct on a phantom scene).
  if (out.scene.roi.centre_ct_mm) {
    out.roi_centre_ct_mm = *out.scene.roi.centre_ct_mm;
    LFTRACK_RETURN_IF_ERROR(check_roi_inside_ct(out.scene, *out.ct));
  } else if (phantom_target) {
    out.roi_centre_ct_mm = *phantom_target + Vector3d(0, 12, 0);
  } else {
    out.roi_centre_ct_mm = out.ct->geometry.centre_mm();
    out.roi_centre_is_volume_centre = true;
    spdlog::warn("no ROI centre for {}; using the volume centre", out.scene.ct.path);
  }
  if (out.scene.registration_origin_ct_mm) {
    out.registration_origin_ct_mm = *out.scene.registration_origin_ct_mm;
  } else {
    out.registration_origin_ct_mm =
        phantom_target && !out.scene.roi.centre_ct_mm ? *phantom_target : out.roi_centre_ct_mm;
  }
  if (out.scene.nominal_T_room_from_ct) {
    out.nominal_T_room_from_ct = *out.scene.nominal_T_room_from_ct;
  } else {
    out.nominal_T_room_from_ct = tracking::Pose::Identity();
    out.nominal_T_room_from_ct.translation() = -out.registration_origin_ct_mm;
  }
  LFTRACK_RETURN_IF_ERROR(check_origin_inside_roi(out));
  for (const DetectorSpec& d : out.scene.detectors) {
    auto w = roi_window(d.view, out.nominal_T_room_from_ct, out.roi_centre_ct_mm, out.scene.roi.size_mm);
    if (!w.ok()) return w.status().with_context(out.scene.where("roi"));
    out.roi_windows.push_back(*w);
  }
  if (out.scene.roi.mask) {
    auto masks = project_roi_mask(out);
    if (!masks.ok()) return masks.status();
    out.roi_masks = std::move(*masks);
  }
  auto exposure = scene_exposure(out);
  if (!exposure.ok()) return exposure.status();
  out.exposure = *exposure;
  return out;
}

}  // namespace lftrack::session
