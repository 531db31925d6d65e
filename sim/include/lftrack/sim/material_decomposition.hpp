#pragma once
// A CT split into water- and bone-equivalent densities (issue 21, "Spectrum"), so that the
// simulator can attenuate each with its own energy dependence at the imaging beam's spectrum.
//
// The planning CT maps HU to attenuation at its own effective energy: mu = mu_water(E_ct) (1 +
// HU/1000). Each voxel is read as a mix that reproduces that mu exactly at E_ct:
//   HU <= 0            water of density 1 + HU/1000 (air, lung, fat), no bone;
//   0 < HU < HU_bone   water and cortical bone mixed by volume, bone fraction HU / HU_bone;
//   HU >= HU_bone      cortical bone, denser in proportion to mu (no water),
// where HU_bone = 1000 (rho_bone (mu/rho)_bone(E_ct) / (mu/rho)_water(E_ct) - 1) is cortical bone's
// CT number at E_ct (about 1,550 HU at 70 keV). At the imaging beam's lower mean energy bone
// attenuates more, relative to water, than the planning CT's single mu says: the bias this
// decomposition lets the frames carry.
//
// Volumes hold mass per area per millimetre (g/cm^2 per mm, i.e. 0.1 x g/cm^3), so that a ray
// caster's line integral over millimetres is a mass thickness in g/cm^2. They are stored as
// MuVolume so every renderer can cast through them.

#include <Eigen/Core>
#include <vector>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::sim {

struct MassThicknessVolumes {
  tracking::MuVolume water;  // g/cm^2 per mm
  tracking::MuVolume bone;   // g/cm^2 per mm (cortical bone, ICRU-44)
};

// CT number of cortical bone at `ct_effective_kev`.
double cortical_bone_hu(double ct_effective_kev);

// Splits `ct` as above. `ct_effective_kev` in [30, 150]. Non-finite HU read as air.
Result<MassThicknessVolumes> decompose_ct(const tracking::CtVolume& ct, double ct_effective_kev,
                                         tracking::ThreadPool* pool = nullptr);

// Bone-equivalent mass per area per mm (g/cm^2 per mm) that attenuates at `ct_effective_kev` as
// `mu_per_mm` does: how steel markers enter the bone volume.
float bone_equivalent_of(double mu_per_mm, double ct_effective_kev);

}  // namespace lftrack::sim
