#include "lftrack/sim_devices/simulated_patient.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"

#include "lftrack/phantom/implanted_markers.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/sim/anatomy_deformation.hpp"
#include "lftrack/sim/material_decomposition.hpp"
#include "lftrack/sim/sphere_markers.hpp"
#include "lftrack/sim/surround_frames.hpp"

namespace lftrack::sim_devices {

using session::load_or_build_light_fields;
using session::PreparedScene;

sim::PatientRenderers SimulatedPatient::renderers() const {
  sim::PatientRenderers r;
  r.attenuation = attenuation_renderer.get();
  r.water = water_renderer.get();
  r.bone = bone_renderer.get();
  return r;
}

sim::PatientRenderers SimulatedPatient::surround_renderers() const {
  sim::PatientRenderers r;
  r.attenuation = surround_attenuation.get();
  r.water = surround_water.get();
  r.bone = surround_bone.get();
  return r;
}

Result<SimulatedPatient> simulated_patient_volumes(const PreparedScene& p,
                                                   const sim_spec::XrayPhysicsSpec& physics,
                                                   std::uint64_t anatomy_seed, tracking::ThreadPool* pool) {
  LFTRACK_RETURN_IF_ERROR(sim_spec::check_physics(physics));
  SimulatedPatient patient;
  if (!physics.anatomy && !physics.spectrum) {
    patient.attenuation = p.mu;
    return patient;
  }
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
    patient.water = std::make_shared<const tracking::MuVolume>(std::move(split->water));
    patient.bone = std::make_shared<const tracking::MuVolume>(std::move(split->bone));
  } else {
    patient.attenuation =
        std::make_shared<const tracking::MuVolume>(tracking::to_attenuation(*ct, p.scene.ct.mu_water_per_mm));
  }
  return patient;
}

Result<SimulatedPatient> make_simulated_patient(const PreparedScene& p,
                                                const sim_spec::XrayPhysicsSpec& physics,
                                                std::uint64_t anatomy_seed, tracking::ThreadPool* pool,
                                                tracking::ThreadPool* render_pool,
                                                const std::filesystem::path* frame_fields_dir,
                                                bool with_surround) {
  auto made = simulated_patient_volumes(p, physics, anatomy_seed, pool);
  if (!made.ok()) return made.status();
  SimulatedPatient patient = std::move(made).value();
  // Volume `v` (called `name`) as Siddon renders it, or (`from_fields`) as its light fields do;
  // while `surround`, Siddon over its coarse copy (surround_frames.hpp).
  bool surround = false;
  auto renderer = [&](std::shared_ptr<const tracking::MuVolume> v, const char* name,
                      bool from_fields) -> Result<std::shared_ptr<const tracking::DrrRenderer>> {
    if (surround) v = std::make_shared<const tracking::MuVolume>(sim::surround_volume(*v));
    tracking::RendererOptions options;
    options.pool = render_pool;
    if (from_fields) {
      options.light_field_mips = false;  // whole-detector frames: no coarse pixels to average
      auto fields =
          load_or_build_light_fields(p, *v, p.scene.sim.light_field, *frame_fields_dir / name, pool);
      if (!fields.ok())
        return fields.status().with_context(std::string("the simulated patient's ") + name + " fields");
      options.light_fields = *fields;
    }
    auto r = tracking::make_renderer(from_fields ? "lightfield" : "siddon", std::move(v), options);
    if (!r.ok()) return r.status();
    return std::shared_ptr<const tracking::DrrRenderer>(std::move(r).value());
  };
  // The scene's markers as the spheres they are (sphere_markers.hpp), added to the renderers
  // below, not written into the voxels: in 3 mm slices a voxel marker sits at its slice's centre.
  // The planning CT's own clipped image of a marker stays, as it would in a patient's CT. Steel in
  // the attenuation volume; with a spectrum, its bone equivalent in the bone volume.
  const auto& f = p.scene.fiducials;
  const double marker_value_per_mm =
      physics.spectrum ? sim::bone_equivalent_of(phantom::kSteelMuPerMm, physics.spectrum->ct_effective_kev)
                       : double(phantom::kSteelMuPerMm);
  std::vector<sim::SphereMarker> markers;
  if (f.insert)
    for (const Eigen::Vector3d& c : f.positions_ct_mm)
      markers.push_back({c, f.radius_mm, marker_value_per_mm});
  // The frames' renderers (fields: from light fields), the marked volume's with the markers.
  auto set = [&](bool fields, std::shared_ptr<const tracking::DrrRenderer>* attenuation,
                 std::shared_ptr<const tracking::DrrRenderer>* water,
                 std::shared_ptr<const tracking::DrrRenderer>* bone) -> Status {
    if (patient.attenuation) {
      auto r = renderer(patient.attenuation, "attenuation", fields);
      if (!r.ok()) return r.status();
      auto with = sim::with_sphere_markers(*r, markers);
      if (!with.ok()) return with.status().with_context("the simulated patient's markers");
      *attenuation = *with;
      return {};
    }
    auto w = renderer(patient.water, "water", fields);
    if (!w.ok()) return w.status();
    auto b = renderer(patient.bone, "bone", fields);
    if (!b.ok()) return b.status();
    auto with = sim::with_sphere_markers(*b, markers);
    if (!with.ok()) return with.status().with_context("the simulated patient's markers");
    *water = *w;
    *bone = *with;
    return {};
  };
  LFTRACK_RETURN_IF_ERROR(set(frame_fields_dir != nullptr, &patient.attenuation_renderer,
                              &patient.water_renderer, &patient.bone_renderer));
  if (with_surround) {
    surround = true;
    LFTRACK_RETURN_IF_ERROR(
        set(false, &patient.surround_attenuation, &patient.surround_water, &patient.surround_bone));
  }
  return patient;
}

std::uint64_t scene_anatomy_seed(const PreparedScene& p) {
  return p.scene.sim.physics.anatomy ? p.scene.sim.physics.anatomy->seed : 1;
}

Result<std::shared_ptr<const SimulatedPatient>> make_scene_patient(
    const PreparedScene& p, const std::filesystem::path& light_field_dir, tracking::ThreadPool* pool) {
  const sim_spec::XrayPhysicsSpec& physics = p.scene.sim.physics;
  if (physics.ideal()) return std::shared_ptr<const SimulatedPatient>();
  const std::filesystem::path fields = sim_frame_fields_dir(p, light_field_dir);
  auto patient = make_simulated_patient(p, physics, scene_anatomy_seed(p), pool, nullptr,
                                        p.scene.sim.renderer == "lightfield" ? &fields : nullptr, true);
  if (!patient.ok()) return patient.status();
  return std::make_shared<const SimulatedPatient>(std::move(patient).value());
}

Result<SceneImager> SceneImager::create(const PreparedScene& p, const sim_spec::XrayPhysicsSpec& physics,
                                        int margin_px) {
  SceneImager imager;
  imager.scene_ = &p;
  imager.model_ = scene_detector_model(p);
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    const auto& view = p.scene.detectors[i].view;
    auto s = sim::FrameSynthesizer::create(sim_frame_window(p, int(i), margin_px), imager.model_, physics,
                                           view.rows, view.cols,
                                           0.5 * (view.pitch_col_mm + view.pitch_row_mm), i + 1);
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
    LFTRACK_RETURN_IF_ERROR(
        synthesizers_[i]
            ->synthesize(patient.renderers(), gold, view, seed * 7919 + i, frames.back().view())
            .with_context("view " + view.name));
  }
  return frames;
}

void SceneImager::forget_previous_frames() {
  for (auto& s : synthesizers_) s->forget_previous_frame();
}

tracking::DetectorCorrection SceneImager::correction() const {
  return sim::detector_correction(model_);
}

}  // namespace lftrack::sim_devices
