#include "lftrack/sim/xray_physics.hpp"

#include <sstream>

namespace lftrack::sim {

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

std::vector<std::string> physics_preset_names() { return {"ideal", "clinical"}; }

Result<XrayPhysicsSpec> physics_preset(const std::string& name) {
  XrayPhysicsSpec p;
  if (name == "ideal") return p;
  if (name == "clinical") return clinical_physics();
  return invalid_argument("unknown physics preset '" + name + "' (ideal, clinical)");
}

Status check_physics(const XrayPhysicsSpec& p) {
  if (p.spectrum) {
    LFTRACK_RETURN_IF_ERROR(make_spectrum(p.spectrum->spectrum).status());
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

}  // namespace lftrack::sim
