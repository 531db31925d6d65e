#pragma once
// The patient the simulator images (issue 21): the planning CT's anatomy, deformed by one draw of
// the scene's sim.physics.anatomy when it has one, with the scene's steel markers, as the volumes
// its frames need (attenuation, or with a spectrum water and bone mass thicknesses), and the
// scene's detectors exposing it with the rest of sim.physics.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <vector>

#include "lftrack/session/scene.hpp"
#include "lftrack/sim/synthetic_frames.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/drr_renderer.hpp"

namespace lftrack::sim_devices {

struct SimulatedPatient {
  // Set: attenuation (mono-energetic frames), or water and bone (a spectrum).
  std::shared_ptr<const tracking::MuVolume> attenuation, water, bone;
  std::shared_ptr<const tracking::DrrRenderer> attenuation_renderer, water_renderer, bone_renderer;
  // The same volumes (block-averaged: sim::surround_volume) and markers by Siddon, for the
  // detector outside the ROI windows (surround_frames.hpp), which light fields made for the
  // windows do not cover. Made only when asked for (make_simulated_patient's `with_surround`).
  std::shared_ptr<const tracking::DrrRenderer> surround_attenuation, surround_water, surround_bone;
  sim::PatientRenderers renderers() const;
  sim::PatientRenderers surround_renderers() const;
};

// The patient's volumes for `physics` with anatomy draw `anatomy_seed` (attenuation, or with a
// spectrum water and bone), built on `pool`, without renderers. Ideal physics reuses the scene's
// attenuation volume without a copy.
Result<SimulatedPatient> simulated_patient_volumes(const session::PreparedScene& scene,
                                                   const sim_spec::XrayPhysicsSpec& physics,
                                                   std::uint64_t anatomy_seed, tracking::ThreadPool* pool);

// The patient's volumes (above) with their renderers, the scene's markers added to them as exact
// spheres: Siddon, rendering on `render_pool` (null: the caller's thread); or with
// `frame_fields_dir` light fields of the scene's sim.light_field, one per view and volume in
// <frame_fields_dir>/<volume> (attenuation, water, bone), loaded where up to date and built (and
// saved) where not. `with_surround`: the surround renderers too, for whole-detector frames.
Result<SimulatedPatient> make_simulated_patient(const session::PreparedScene& scene,
                                                const sim_spec::XrayPhysicsSpec& physics,
                                                std::uint64_t anatomy_seed, tracking::ThreadPool* pool,
                                                tracking::ThreadPool* render_pool = nullptr,
                                                const std::filesystem::path* frame_fields_dir = nullptr,
                                                bool with_surround = false);

// The scene's own patient's anatomy draw: sim.physics.anatomy.seed (1 without anatomy).
std::uint64_t scene_anatomy_seed(const session::PreparedScene& scene);

// The patient of the scene's own sim.physics for the simulated loop, or null where the physics is
// ideal (the loop's frame renderer then renders the world anatomy). Rendered as sim.renderer
// says: Siddon, or with `lightfield` from light fields of the day's volumes in
// sim_frame_fields_dir()/{attenuation,water,bone}, built before the first frame where missing.
Result<std::shared_ptr<const SimulatedPatient>> make_scene_patient(
    const session::PreparedScene& scene, const std::filesystem::path& light_field_dir,
    tracking::ThreadPool* pool);

// The scene's detectors with `physics`: one frame synthesizer per detector over its ROI window
// grown by `margin_px`, each detector with its own fixed pattern. Keeps each detector's previous
// frame for lag.
class SceneImager {
 public:
  static Result<SceneImager> create(const session::PreparedScene& scene,
                                    const sim_spec::XrayPhysicsSpec& physics, int margin_px = 16);
  // Raw whole-detector frames at `gold`; the same seed and history give the same frames.
  Result<std::vector<tracking::Image<std::uint16_t>>> expose(const SimulatedPatient& patient,
                                                             const tracking::Pose& gold_T_room_from_ct,
                                                             std::uint64_t seed);
  // The next exposure carries no lag.
  void forget_previous_frames();
  // What preprocessing needs to undo the detectors' levels.
  tracking::DetectorCorrection correction() const;

 private:
  const session::PreparedScene* scene_ = nullptr;
  sim::DetectorModel model_;
  std::vector<std::shared_ptr<sim::FrameSynthesizer>> synthesizers_;
};

}  // namespace lftrack::sim_devices
