#include "lftrack/sim/material_decomposition.hpp"

#include <algorithm>
#include <cmath>

#include "lftrack/sim/xray_spectrum.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::sim {

double cortical_bone_hu(double e) {
  const double mu_w = mass_attenuation_cm2_per_g(Material::kWater, e);
  const double mu_b = mass_attenuation_cm2_per_g(Material::kCorticalBone, e) *
                      material_density_g_per_cm3(Material::kCorticalBone);
  return 1000 * (mu_b / mu_w - 1);
}

float bone_equivalent_of(double mu_per_mm, double e) {
  // mu [1/mm] = (mu/rho) [cm^2/g] * rho [g/cm^3] / 10; the volume holds rho / 10.
  return float(mu_per_mm / mass_attenuation_cm2_per_g(Material::kCorticalBone, e));
}

Result<MassThicknessVolumes> decompose_ct(const tracking::CtVolume& ct, double e, tracking::ThreadPool* pool) {
  if (!(e >= 30 && e <= 150)) return out_of_range("decomposition: ct_effective_kev must be in [30, 150]");
  LFTRACK_RETURN_IF_ERROR(ct.geometry.validate());
  if (ct.values.size() != std::size_t(ct.geometry.voxel_count()))
    return invalid_argument("decomposition: the CT has the wrong number of values");
  const double hu_bone = cortical_bone_hu(e);
  const double rho_bone = material_density_g_per_cm3(Material::kCorticalBone);
  MassThicknessVolumes out;
  out.water.geometry = ct.geometry;
  out.bone.geometry = ct.geometry;
  out.water.values.resize(ct.values.size());
  out.bone.values.resize(ct.values.size());
  auto split = [&](std::size_t begin, std::size_t end) {
    for (std::size_t i = begin; i < end; ++i) {
      const double hu = std::isfinite(ct.values[i]) ? double(ct.values[i]) : -1000.0;
      double water = 0, bone = 0;  // g/cm^3
      if (hu <= 0) {
        water = std::max(0.0, 1 + hu / 1000);
      } else if (hu < hu_bone) {
        const double f = hu / hu_bone;
        water = 1 - f;
        bone = f * rho_bone;
      } else {
        bone = rho_bone * (1 + hu / 1000) / (1 + hu_bone / 1000);
      }
      out.water.values[i] = float(water / 10);
      out.bone.values[i] = float(bone / 10);
    }
  };
  const std::size_t n = ct.values.size();
  if (pool == nullptr) {
    split(0, n);
  } else {
    const std::size_t chunk = 1 << 20;
    const int tasks = int((n + chunk - 1) / chunk);
    pool->parallel_for(tasks, 1, [&](int begin, int end) {
      split(std::size_t(begin) * chunk, std::min(n, std::size_t(end) * chunk));
    });
  }
  return out;
}

}  // namespace lftrack::sim
