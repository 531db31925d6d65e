#pragma once
// The simulator's detectors (issue 51): per view, a frame synthesizer over the ROI window grown
// by a margin (synthetic_frames.hpp), and the rest of the detector coarser (surround_frames.hpp),
// writing whole-detector frames of raw counts. SimFrameSource exposes them each cycle; `lftrack
// bench frames` times the same objects. Nothing allocates after create().

#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "lftrack/session/room_simulator.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/sim/surround_frames.hpp"
#include "lftrack/sim/synthetic_frames.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/image.hpp"

namespace lftrack::sim_devices {

class SimDetectors {
 public:
  // Frames of `patient` (realistic physics), or of `ideal` (the scene's world anatomy, ideal
  // frames) when `patient` is null. `model` is scene_detector_model(scene) or a variant of it.
  static Result<SimDetectors> create(const session::PreparedScene& scene,
                                     std::shared_ptr<const tracking::DrrRenderer> ideal,
                                     std::shared_ptr<const SimulatedPatient> patient,
                                     const sim::DetectorModel& model,
                                     const session::SimDetectorsOptions& options = {});
  // Every view at `pose` into frames[v] (whole detectors, sized by the scene); view v draws its
  // noise from seed + v. Pixels neither the window nor the surround writes are left as they are.
  Status expose(const tracking::Pose& gold_T_room_from_ct, std::uint64_t seed,
                std::vector<tracking::Image<std::uint16_t>>* frames);
  // Whole-detector frames of the scene's sizes, zeros.
  std::vector<tracking::Image<std::uint16_t>> make_frames() const;
  // The finely rendered window of view v, and pixels written per exposure (all views).
  const tracking::PixelWindow& window(std::size_t view) const { return synthesizers_[view]->window(); }
  std::int64_t written_pixels() const;
  bool whole_detector() const { return !surrounds_.empty(); }
  void forget_previous_frames();

 private:
  const session::PreparedScene* scene_ = nullptr;
  std::shared_ptr<const tracking::DrrRenderer> ideal_;
  std::shared_ptr<const SimulatedPatient> patient_;
  std::shared_ptr<const tracking::DrrRenderer> surround_ideal_;  // Siddon, coarse world anatomy
  std::vector<std::unique_ptr<sim::FrameSynthesizer>> synthesizers_;
  std::vector<std::unique_ptr<sim::SurroundSynthesizer>> surrounds_;
};

// The simulated detectors as `lftrack register --sim` and `lftrack commission` expose them: each
// ROI window exact (Siddon, a 16-pixel margin), the rest of each detector coarser; the scene's
// imaging physics (sim.physics) on its simulated patient, or the world anatomy where the physics
// is ideal. `correction` is how such frames are corrected on a detector without a calibration
// file of its own (realistic physics: the simulator's detector model), or empty.
struct SceneSimDetectors {
  SimDetectors detectors;
  std::optional<tracking::DetectorCorrection> correction;
};
Result<SceneSimDetectors> make_scene_sim_detectors(const session::PreparedScene& scene,
                                                   tracking::ThreadPool* pool);

}  // namespace lftrack::sim_devices
