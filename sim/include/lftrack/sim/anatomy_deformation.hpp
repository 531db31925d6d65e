#pragma once
// The patient on the day is not the planning CT (issue 21, "Anatomy"): soft tissue and organs
// deform smoothly, more the farther they are from the target; the vertebrae above and below the
// target move a little relative to it (the reason the papers crop an ROI); in the chest the
// anterior anatomy moves with breathing. The target itself stays rigid, so the gold pose is
// still defined: the displacement is exactly zero inside the target's box.
//
// Frame: the CT frame (patient LPS, mm): +z is superior, -y anterior. The target's box is
// axis-aligned in it, centred on the target (the scene's registration origin).
//
// Displacement d(x), the sum of
//   adjacent   above the box's top, the rigid motion T_above - I of a segment pivoting on the top
//              face's centre (likewise below), blended in over `disc_mm` (the disc) and confined
//              laterally to a column around the box's footprint (fading over `ramp_mm`);
//   soft       a smooth random field (per component a sum of four plane waves of wavelength
//              about `soft_tissue_scale_mm`, rms `soft_tissue_mm` over the vector) weighted from
//              0 at the box to 1 at `ramp_mm` from it;
//   breathing  a superior-inferior shift of `breathing_mm` times a drawn phase in [0, 1], for
//              anatomy anterior of the target, with the soft weight.
// The patient volume is the CT resampled at x - d(x) (d is small and smooth, so this inverts the
// map to well under a voxel); outside the CT reads as air.
//
// Typical values (the clinical preset's): soft tissue 3 mm rms (interfraction organ and skin
// displacement of 2-5 mm, e.g. Langen and Jones, IJROBP 50 (2001) 265); adjacent vertebrae 1 mm
// and 1 degree per axis (intervertebral motion between set-ups in spine SBRT); breathing 0
// except for thoracic scenes (10 mm superior-inferior at full inhale, Seppenwoolde et al.,
// IJROBP 53 (2002) 822).

#include <Eigen/Core>
#include <cstdint>

#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::sim {

// One draw of the deformation.
class AnatomyDeformation {
 public:
  AnatomyDeformation(const sim_spec::AnatomySpec& spec, const Eigen::Vector3d& target_centre_ct_mm,
                     std::uint64_t seed);
  Eigen::Vector3d displacement_mm(const Eigen::Vector3d& x_ct_mm) const;
  // Inside the target's box (where the displacement is zero).
  bool in_target(const Eigen::Vector3d& x_ct_mm) const;
  double breathing_phase() const { return breathing_phase_; }

 private:
  sim_spec::AnatomySpec spec_;
  Eigen::Vector3d centre_, half_;
  tracking::Pose above_, below_;  // CT from CT: the adjacent segments' rigid motions
  Eigen::Vector3d wave_k_[3][4], wave_amplitude_;
  double wave_phase_[3][4] = {};
  double breathing_phase_ = 0;
};

// The CT as the patient is on the day: resampled through one draw of the deformation.
Result<tracking::CtVolume> deform_ct(const tracking::CtVolume& ct, const AnatomyDeformation& deformation,
                                     tracking::ThreadPool* pool = nullptr);

}  // namespace lftrack::sim
