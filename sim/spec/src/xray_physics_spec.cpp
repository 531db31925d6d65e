#include "lftrack/sim_spec/xray_physics_spec.hpp"

#include <cmath>
#include <sstream>

namespace lftrack::sim_spec {

namespace {

// Whether v is a finite number in [lo, hi] (NaN and infinities are not).
bool in(double v, double lo, double hi) {
  return std::isfinite(v) && v >= lo && v <= hi;
}

}  // namespace

BeamSpec clinical_beam() {
  BeamSpec b;
  b.spectrum.kvp = 120;
  b.spectrum.filtration_mm_al = 2.5;
  b.ct_effective_kev = 70;
  return b;
}

ScatterSpec clinical_scatter() {
  ScatterSpec s;
  s.spr_per_cm = 0.05;
  s.kernel_sigma_mm = 40;
  s.grid = true;
  return s;
}

DetectorEffectsSpec clinical_detector() {
  DetectorEffectsSpec d;
  d.glare_fraction = 0.05;
  d.glare_sigma_mm = 3;
  d.lag_fraction = 0.03;
  d.gain_smooth_rms = 0.005;
  d.gain_pixel_rms = 0.003;
  d.defective_pixel_fraction = 0.001;
  d.defective_lines = 2;
  d.heel_gradient = 0.03;
  return d;
}

AnatomySpec clinical_anatomy() {
  AnatomySpec a;
  a.soft_tissue_mm = 3;
  a.adjacent_translation_mm = 1;
  a.adjacent_rotation_deg = 1;
  return a;
}

XrayPhysicsSpec clinical_physics() {
  XrayPhysicsSpec p;
  p.spectrum = clinical_beam();
  p.scatter = clinical_scatter();
  p.detector = clinical_detector();
  p.anatomy = clinical_anatomy();
  return p;
}

std::vector<std::string> physics_preset_names() {
  return {"ideal", "clinical"};
}

Result<XrayPhysicsSpec> physics_preset(const std::string& name) {
  XrayPhysicsSpec p;
  if (name == "ideal") return p;
  if (name == "clinical") return clinical_physics();
  return invalid_argument("unknown physics preset '" + name + "' (ideal, clinical)");
}

Status check_physics(const XrayPhysicsSpec& p) {
  if (p.spectrum) {
    LFTRACK_RETURN_IF_ERROR(check_spectrum_spec(p.spectrum->spectrum));
    if (!(p.spectrum->ct_effective_kev >= 30 && p.spectrum->ct_effective_kev <= 150))
      return out_of_range("spectrum: ct_effective_kev must be in [30, 150]");
  }
  if (p.scatter) LFTRACK_RETURN_IF_ERROR(check_scatter_spec(*p.scatter));
  if (p.detector) LFTRACK_RETURN_IF_ERROR(check_detector_effects(*p.detector));
  if (p.anatomy) LFTRACK_RETURN_IF_ERROR(check_anatomy_spec(*p.anatomy));
  return {};
}

std::string describe(const XrayPhysicsSpec& p) {
  if (p.ideal()) return "ideal (mono-energetic DRRs of the planning CT)";
  std::ostringstream s;
  const char* sep = "";
  if (p.spectrum) {
    s << sep << "spectrum " << p.spectrum->spectrum.kvp << " kVp, " << p.spectrum->spectrum.filtration_mm_al
      << " mm Al (CT at " << p.spectrum->ct_effective_kev << " keV)";
    sep = "; ";
  }
  if (p.scatter) {
    s << sep << "scatter " << p.scatter->spr_per_cm << "/cm, " << p.scatter->kernel_sigma_mm << " mm"
      << (p.scatter->grid ? ", grid" : "");
    sep = "; ";
  }
  if (p.detector) {
    const auto& d = *p.detector;
    s << sep << "detector glare " << d.glare_fraction << ", lag " << d.lag_fraction << ", gain "
      << d.gain_smooth_rms << "/" << d.gain_pixel_rms << ", defects " << d.defective_pixel_fraction << " + "
      << d.defective_lines << " lines, heel " << d.heel_gradient;
    sep = "; ";
  }
  if (p.anatomy) {
    const auto& a = *p.anatomy;
    s << sep << "anatomy soft " << a.soft_tissue_mm << " mm, adjacent " << a.adjacent_translation_mm << " mm/"
      << a.adjacent_rotation_deg << " deg, breathing " << a.breathing_mm << " mm";
  }
  return s.str();
}

Status check_spectrum_spec(const SpectrumSpec& spec) {
  if (!(spec.kvp >= 40 && spec.kvp <= 150))
    return out_of_range("spectrum: kvp must be in [40, 150] (the attenuation tables end at 150 keV)");
  if (!(spec.filtration_mm_al >= 0 && spec.filtration_mm_al <= 20))
    return out_of_range("spectrum: filtration_mm_al must be in [0, 20]");
  // Below 0.01 keV the bins (over 10-150 keV, 14,000 of them) tell nothing more, and far below it
  // their count overflows.
  if (!(spec.bin_kev >= 0.01 && spec.bin_kev <= 10))
    return out_of_range("spectrum: bin_kev must be in [0.01, 10]");
  return {};
}

Status check_scatter_spec(const ScatterSpec& s) {
  if (!(s.spr_per_cm >= 0 && s.spr_per_cm <= 1)) return out_of_range("scatter: spr_per_cm must be in [0, 1]");
  if (!(s.kernel_sigma_mm > 0 && s.kernel_sigma_mm <= 500))
    return out_of_range("scatter: kernel_sigma_mm must be in (0, 500]");
  if (!(s.grid_primary_transmission > 0 && s.grid_primary_transmission <= 1) ||
      !(s.grid_scatter_transmission >= 0 && s.grid_scatter_transmission <= s.grid_primary_transmission))
    return out_of_range("scatter: grid transmissions must satisfy 0 <= scatter <= primary <= 1, primary > 0");
  return {};
}

Status check_detector_effects(const DetectorEffectsSpec& s) {
  if (!in(s.glare_fraction, 0, 0.5)) return out_of_range("detector: glare_fraction must be in [0, 0.5]");
  if (!in(s.glare_sigma_mm, 0.01, 100))
    return out_of_range("detector: glare_sigma_mm must be in [0.01, 100]");
  if (!in(s.lag_fraction, 0, 0.5)) return out_of_range("detector: lag_fraction must be in [0, 0.5]");
  if (!in(s.gain_smooth_rms, 0, 0.2) || !in(s.gain_pixel_rms, 0, 0.2))
    return out_of_range("detector: gain_smooth_rms and gain_pixel_rms must be in [0, 0.2]");
  if (!in(s.defective_pixel_fraction, 0, 0.1))
    return out_of_range("detector: defective_pixel_fraction must be in [0, 0.1]");
  if (s.defective_lines < 0 || s.defective_lines > 8)
    return out_of_range("detector: defective_lines must be 0-8");
  if (!in(s.heel_gradient, -0.5, 0.5)) return out_of_range("detector: heel_gradient must be in [-0.5, 0.5]");
  return {};
}

Status check_anatomy_spec(const AnatomySpec& s) {
  if (!in(s.soft_tissue_mm, 0, 30)) return out_of_range("anatomy: soft_tissue_mm must be in [0, 30]");
  if (!in(s.soft_tissue_scale_mm, 10, 1000))
    return out_of_range("anatomy: soft_tissue_scale_mm must be in [10, 1000]");
  if (!in(s.ramp_mm, 1, 500)) return out_of_range("anatomy: ramp_mm must be in [1, 500]");
  if (!in(s.adjacent_translation_mm, 0, 10))
    return out_of_range("anatomy: adjacent_translation_mm must be in [0, 10]");
  if (!in(s.adjacent_rotation_deg, 0, 10))
    return out_of_range("anatomy: adjacent_rotation_deg must be in [0, 10]");
  if (!in(s.disc_mm, 1, 100)) return out_of_range("anatomy: disc_mm must be in [1, 100]");
  if (!in(s.breathing_mm, 0, 40)) return out_of_range("anatomy: breathing_mm must be in [0, 40]");
  for (int a = 0; a < 3; ++a)
    if (!in(s.target_size_mm[a], 1, 1000))
      return out_of_range("anatomy: target_size_mm must be in [1, 1000] per axis");
  return {};
}

}  // namespace lftrack::sim_spec
