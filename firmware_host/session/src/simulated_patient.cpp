#include "lftrack/host/simulated_patient.hpp"

#include "lftrack/host/scene_registration.hpp"
#include "lftrack/sim/anatomy_deformation.hpp"
#include "lftrack/sim/material_decomposition.hpp"
#include "lftrack/sim/sphere_markers.hpp"

namespace lftrack::host {

sim::PatientRenderers SimulatedPatient::renderers() const {
  sim::PatientRenderers r;
  r.attenuation = attenuation_renderer.get();
  r.water = water_renderer.get();
  r.bone = bone_renderer.get();
  return r;
}

Result<SimulatedPatient> make_simulated_patient(const PreparedScene& p, const sim::XrayPhysicsSpec& physics,
                                                std::uint64_t anatomy_seed, tracking::ThreadPool* pool,
                                                tracking::ThreadPool* render_pool) {
  LFTRACK_RETURN_IF_ERROR(sim::check_physics(physics));
  SimulatedPatient patient;
  auto siddon = [&](std::shared_ptr<const tracking::MuVolume> v) -> Result<std::shared_ptr<const tracking::DrrRenderer>> {
    tracking::RendererOptions options;
    options.pool = render_pool;
    auto r = tracking::make_renderer("siddon", std::move(v), options);
    if (!r.ok()) return r.status();
    return std::shared_ptr<const tracking::DrrRenderer>(std::move(r).value());
  };
  // The scene's markers as the spheres they are (sphere_markers.hpp), added to the renderers
  // below, not written into the voxels: in 3 mm slices a voxel marker sits at its slice's centre.
  // The planning CT's own clipped image of a marker stays, as it would in a patient's CT.
  const auto& f = p.scene.fiducials;
  auto markers = [&](double value_per_mm) {
    std::vector<sim::SphereMarker> out;
    if (f.insert)
      for (const Eigen::Vector3d& c : f.positions_ct_mm) out.push_back({c, f.radius_mm, value_per_mm});
    return out;
  };
  double marker_value_per_mm = sim::kSteelMuPerMm;  // in the attenuation volume; bone-equivalent below
  if (!physics.anatomy && !physics.spectrum) {
    patient.attenuation = p.mu;
  } else {
    // The day's anatomy (the CT already shows the markers, clipped).
    std::shared_ptr<const tracking::CtVolume> ct = p.ct;
    if (physics.anatomy) {
      const sim::AnatomyDeformation draw(*physics.anatomy, p.registration_origin_ct_mm, anatomy_seed);
      auto moved = sim::deform_ct(*p.ct, draw, pool);
      if (!moved.ok()) return moved.status().with_context("the simulated patient's anatomy");
      ct = std::make_shared<const tracking::CtVolume>(std::move(moved).value());
    }
    if (physics.spectrum) {
      auto split = sim::decompose_ct(*ct, physics.spectrum->ct_effective_kev, pool);
      if (!split.ok()) return split.status().with_context("the simulated patient's water and bone");
      marker_value_per_mm = sim::bone_equivalent_of(sim::kSteelMuPerMm, physics.spectrum->ct_effective_kev);
      patient.water = std::make_shared<const tracking::MuVolume>(std::move(split->water));
      patient.bone = std::make_shared<const tracking::MuVolume>(std::move(split->bone));
    } else {
      patient.attenuation =
          std::make_shared<const tracking::MuVolume>(tracking::to_attenuation(*ct, p.scene.ct.mu_water_per_mm));
    }
  }
  if (patient.attenuation) {
    auto r = siddon(patient.attenuation);
    if (!r.ok()) return r.status();
    auto with = sim::with_sphere_markers(*r, markers(marker_value_per_mm));
    if (!with.ok()) return with.status().with_context("the simulated patient's markers");
    patient.attenuation_renderer = *with;
  } else {
    auto w = siddon(patient.water);
    if (!w.ok()) return w.status();
    auto b = siddon(patient.bone);
    if (!b.ok()) return b.status();
    auto with = sim::with_sphere_markers(*b, markers(marker_value_per_mm));
    if (!with.ok()) return with.status().with_context("the simulated patient's markers");
    patient.water_renderer = *w;
    patient.bone_renderer = *with;
  }
  return patient;
}

Result<std::shared_ptr<const SimulatedPatient>> make_scene_patient(const PreparedScene& p,
                                                                   tracking::ThreadPool* pool) {
  const sim::XrayPhysicsSpec& physics = p.scene.sim.physics;
  if (physics.ideal()) return std::shared_ptr<const SimulatedPatient>();
  if (p.scene.sim.renderer == "lightfield")
    return failed_precondition(
        "sim.physics other than ideal renders frames with Siddon (water and bone, scatter); light-field frames of "
        "realistic physics are not built yet: set sim.renderer: siddon");
  auto patient = make_simulated_patient(p, physics, physics.anatomy ? physics.anatomy->seed : 1, pool);
  if (!patient.ok()) return patient.status();
  return std::make_shared<const SimulatedPatient>(std::move(patient).value());
}

Result<SceneImager> SceneImager::create(const PreparedScene& p, const sim::XrayPhysicsSpec& physics, int margin_px) {
  SceneImager imager;
  imager.scene_ = &p;
  imager.model_ = scene_detector_model(p);
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    const auto& view = p.scene.detectors[i].view;
    auto s = sim::FrameSynthesizer::create(sim_frame_window(p, int(i), margin_px), imager.model_, physics, view.rows,
                                           view.cols, 0.5 * (view.pitch_col_mm + view.pitch_row_mm), i + 1);
    if (!s.ok()) return s.status().with_context("detector " + view.name);
    imager.synthesizers_.push_back(std::shared_ptr<sim::FrameSynthesizer>(std::move(s).value()));
  }
  return imager;
}

Result<std::vector<tracking::Image<std::uint16_t>>> SceneImager::expose(const SimulatedPatient& patient,
                                                                         const tracking::Pose& gold,
                                                                         std::uint64_t seed) {
  std::vector<tracking::Image<std::uint16_t>> frames;
  for (std::size_t i = 0; i < synthesizers_.size(); ++i) {
    const auto& view = scene_->scene.detectors[i].view;
    frames.emplace_back(view.rows, view.cols, 0);
    LFTRACK_RETURN_IF_ERROR(synthesizers_[i]
                                ->synthesize(patient.renderers(), gold, view, seed * 7919 + i, frames.back().view())
                                .with_context("view " + view.name));
  }
  return frames;
}

void SceneImager::forget_previous_frames() {
  for (auto& s : synthesizers_) s->forget_previous_frame();
}

tracking::DetectorCorrection SceneImager::correction() const { return sim::detector_correction(model_); }

}  // namespace lftrack::host
