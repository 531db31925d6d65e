#include "lftrack/sim/xray_spectrum.hpp"

#include <algorithm>
#include <array>
#include <cmath>

namespace lftrack::sim {

using sim_spec::check_spectrum_spec;
using sim_spec::SpectrumSpec;

namespace {

// NIST X-ray mass attenuation coefficients, mu/rho in cm^2/g (J. H. Hubbell and S. M. Seltzer,
// "Tables of X-Ray Mass Attenuation Coefficients and Mass Energy-Absorption Coefficients",
// NIST Standard Reference Database 126, NISTIR 5632; Table 4 for water (liquid) and bone,
// cortical (ICRU-44), Table 3 for aluminium (Z = 13)), at the tables' energies 10-150 keV.
constexpr std::array<double, 10> kEnergyKev = {10, 15, 20, 30, 40, 50, 60, 80, 100, 150};
constexpr std::array<double, 10> kWater = {5.329, 1.673, 0.8096, 0.3756, 0.2683,
                                           0.2269, 0.2059, 0.1837, 0.1707, 0.1505};
constexpr std::array<double, 10> kCorticalBone = {28.51, 9.032, 4.001, 1.331, 0.6655,
                                                  0.4242, 0.3148, 0.2229, 0.1855, 0.1480};
constexpr std::array<double, 10> kAluminium = {26.21, 7.955, 3.441, 1.128, 0.5685,
                                               0.3681, 0.2778, 0.2018, 0.1704, 0.1378};

const std::array<double, 10>& table_of(Material m) {
  switch (m) {
    case Material::kWater: return kWater;
    case Material::kCorticalBone: return kCorticalBone;
    case Material::kAluminium: return kAluminium;
  }
  return kWater;
}

}  // namespace

double material_density_g_per_cm3(Material m) {
  switch (m) {
    case Material::kWater: return 1.0;
    case Material::kCorticalBone: return 1.92;
    case Material::kAluminium: return 2.699;
  }
  return 1.0;
}

double mass_attenuation_cm2_per_g(Material material, double energy_kev) {
  const auto& mu = table_of(material);
  const double e = std::clamp(std::isfinite(energy_kev) ? energy_kev : kEnergyKev.front(), kEnergyKev.front(),
                              kEnergyKev.back());
  std::size_t i = 0;
  while (i + 2 < kEnergyKev.size() && e > kEnergyKev[i + 1]) ++i;
  const double t = (std::log(e) - std::log(kEnergyKev[i])) / (std::log(kEnergyKev[i + 1]) - std::log(kEnergyKev[i]));
  return std::exp((1 - t) * std::log(mu[i]) + t * std::log(mu[i + 1]));
}

double XraySpectrum::mean_energy_kev() const {
  double sum = 0;
  for (std::size_t i = 0; i < energy_kev.size(); ++i) sum += signal_weight[i] * energy_kev[i];
  return sum;
}

Result<XraySpectrum> make_spectrum(const SpectrumSpec& spec) {
  LFTRACK_RETURN_IF_ERROR(check_spectrum_spec(spec));
  XraySpectrum s;
  const double e_min = 10;
  const int bins = std::max(1, int(std::ceil((spec.kvp - e_min) / spec.bin_kev)));
  const double width = (spec.kvp - e_min) / bins;
  const double al_per_cm = material_density_g_per_cm3(Material::kAluminium) * spec.filtration_mm_al / 10;
  double total = 0;
  for (int b = 0; b < bins; ++b) {
    const double e = e_min + (b + 0.5) * width;
    const double fluence = (spec.kvp - e) / e *
                           std::exp(-mass_attenuation_cm2_per_g(Material::kAluminium, e) * al_per_cm);
    const double weight = fluence * e;
    s.energy_kev.push_back(e);
    s.signal_weight.push_back(weight);
    total += weight;
  }
  if (!(total > 0)) return out_of_range("spectrum: no signal left after the filtration");
  for (double& w : s.signal_weight) w /= total;
  return s;
}

namespace {

// mu/rho of water and bone at each bin of a spectrum, looked up once.
struct BinAttenuation {
  std::vector<double> water, bone;
  double water_ref = 0, bone_ref = 0;  // at the mean energy
  explicit BinAttenuation(const XraySpectrum& s) {
    for (double e : s.energy_kev) {
      water.push_back(mass_attenuation_cm2_per_g(Material::kWater, e));
      bone.push_back(mass_attenuation_cm2_per_g(Material::kCorticalBone, e));
    }
    water_ref = mass_attenuation_cm2_per_g(Material::kWater, s.mean_energy_kev());
    bone_ref = mass_attenuation_cm2_per_g(Material::kCorticalBone, s.mean_energy_kev());
  }
  double log_attenuation(const XraySpectrum& s, double w, double b) const {
    // Factor out the mean energy's attenuation so that thick paths do not underflow.
    const double ref = water_ref * w + bone_ref * b;
    double sum = 0;
    for (std::size_t i = 0; i < s.energy_kev.size(); ++i)
      sum += s.signal_weight[i] * std::exp(-(water[i] * w + bone[i] * b - ref));
    return ref - std::log(sum);
  }
};

}  // namespace

double polyenergetic_log_attenuation(const XraySpectrum& spectrum, double water_g_cm2, double bone_g_cm2) {
  return BinAttenuation(spectrum).log_attenuation(spectrum, water_g_cm2, bone_g_cm2);
}

Result<PolyenergeticTable> PolyenergeticTable::create(const XraySpectrum& spectrum, double max_water,
                                                      double max_bone, int water_steps, int bone_steps) {
  if (spectrum.energy_kev.empty()) return invalid_argument("polyenergetic table: empty spectrum");
  if (!(max_water > 0 && max_bone > 0) || water_steps < 2 || bone_steps < 2 || water_steps > 4096 ||
      bone_steps > 4096)
    return invalid_argument("polyenergetic table: positive ranges and 2-4096 steps");
  PolyenergeticTable t;
  t.water_steps_ = water_steps;
  t.bone_steps_ = bone_steps;
  t.water_step_ = float(max_water / (water_steps - 1));
  t.bone_step_ = float(max_bone / (bone_steps - 1));
  t.table_.resize(std::size_t(water_steps) * std::size_t(bone_steps));
  const BinAttenuation mu(spectrum);
  for (int b = 0; b < bone_steps; ++b)
    for (int w = 0; w < water_steps; ++w)
      t.table_[std::size_t(b) * std::size_t(water_steps) + std::size_t(w)] =
          float(mu.log_attenuation(spectrum, w * double(t.water_step_), b * double(t.bone_step_)));
  return t;
}

float PolyenergeticTable::log_attenuation(float water, float bone) const {
  // NaN and negatives read as 0 (air); beyond the table, the last cell extrapolates linearly.
  // (Clamped far beyond the table first, so the integer conversion cannot overflow.)
  const float fw = std::isfinite(water) && water > 0 ? std::min(water / water_step_, 1e6f) : 0.f;
  const float fb = std::isfinite(bone) && bone > 0 ? std::min(bone / bone_step_, 1e6f) : 0.f;
  const int w0 = std::min(int(fw), water_steps_ - 2);
  const int b0 = std::min(int(fb), bone_steps_ - 2);
  const float tw = fw - float(w0), tb = fb - float(b0);
  const float* row0 = &table_[std::size_t(b0) * std::size_t(water_steps_) + std::size_t(w0)];
  const float* row1 = row0 + water_steps_;
  return (1 - tb) * ((1 - tw) * row0[0] + tw * row0[1]) + tb * ((1 - tw) * row1[0] + tw * row1[1]);
}

}  // namespace lftrack::sim
