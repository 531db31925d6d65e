#pragma once
// The imaging beam's physics for realistic synthetic frames (DESIGN.md, "Simulated imaging
// physics"; issue 21): tabulated attenuation of water, cortical bone and aluminium, a
// polyenergetic tungsten-anode spectrum at the imaging kVp after its filtration, and the
// detector signal behind a path of water and bone for that spectrum.
//
// Units: energies in keV, mass attenuation coefficients in cm^2/g, mass thicknesses (line
// integrals of density) in g/cm^2.

#include <vector>

#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::sim {

enum class Material { kWater, kCorticalBone, kAluminium };

// Nominal densities (g/cm^3) of NIST's tables: liquid water 1.0, cortical bone (ICRU-44) 1.92,
// aluminium 2.699.
double material_density_g_per_cm3(Material material);

// mu/rho (cm^2/g, coherent scattering included) from NIST's X-ray mass attenuation tables
// (Hubbell and Seltzer, NIST Standard Reference Database 126 / NISTIR 5632, derived from XCOM),
// interpolated log-log between the tabulated energies 10-150 keV. Energies outside [10, 150]
// are clamped to the table's ends. No absorption edge lies in 10-150 keV for these materials.
double mass_attenuation_cm2_per_g(Material material, double energy_kev);

struct XraySpectrum {
  std::vector<double> energy_kev;  // bin centres
  // Detector signal per bin, normalised to sum 1: the fluence times the energy (an
  // energy-integrating scintillator; its absorption efficiency is taken as 1 over the spectrum).
  std::vector<double> signal_weight;
  double mean_energy_kev() const;  // signal-weighted
};

// The beam of `spec` (sim_spec::SpectrumSpec): a tungsten anode's bremsstrahlung at the kVp
// (Kramers' law: photons per keV proportional to (kVp - E) / E), through the aluminium filtration
// (inherent plus added), in bins from 10 keV to the kVp. Characteristic lines (W K-alpha 59 keV,
// K-beta 67 keV) are left out: at 100-120 kVp they carry a few per cent of the fluence. Fails
// where sim_spec::check_spectrum_spec does.
Result<XraySpectrum> make_spectrum(const sim_spec::SpectrumSpec& spec);

// -ln(signal / open-field signal) behind `water_g_cm2` of water and `bone_g_cm2` of cortical
// bone: the polyenergetic line integral, which grows slower than linearly with thickness (the
// beam hardens). Direct sum over the spectrum's bins.
double polyenergetic_log_attenuation(const XraySpectrum& spectrum, double water_g_cm2, double bone_g_cm2);

// The same, tabulated for per-pixel use: bilinear in (water, bone) on a grid of `water_steps` x
// `bone_steps` up to the given maxima (beyond them: extrapolated along the last cell's slope).
// Within 1e-3 of the direct sum over the grid's range for the default steps (tested).
class PolyenergeticTable {
 public:
  static Result<PolyenergeticTable> create(const XraySpectrum& spectrum, double max_water_g_cm2 = 60,
                                           double max_bone_g_cm2 = 40, int water_steps = 241,
                                           int bone_steps = 161);
  float log_attenuation(float water_g_cm2, float bone_g_cm2) const;

 private:
  std::vector<float> table_;  // bone-major: [b * water_steps + w]
  int water_steps_ = 0, bone_steps_ = 0;
  float water_step_ = 1, bone_step_ = 1;
};

}  // namespace lftrack::sim
