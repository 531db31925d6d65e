// The scene's sim.physics section (docs/scenes.md, "Imaging physics"):
//   physics: clinical                      a preset (ideal, clinical)
//   physics:                               or a preset with per-part changes
//     preset: clinical
//     spectrum: {kvp: 100, filtration_mm_al: 3, ct_effective_kev: 70} | off
//     scatter: {spr_per_cm, kernel_sigma_mm, grid, grid_primary_transmission,
//               grid_scatter_transmission} | off
//     detector: {glare_fraction, glare_sigma_mm, lag_fraction, gain_smooth_rms, gain_pixel_rms,
//                defective_pixel_fraction, defective_lines, heel_gradient} | off
//     anatomy: {soft_tissue_mm, soft_tissue_scale_mm, ramp_mm, adjacent_translation_mm,
//               adjacent_rotation_deg, disc_mm, breathing_mm, target_size_mm, seed} | off
// A part named as a mapping starts from the clinical preset's values of that part.
#include "scene_yaml.hpp"

namespace lftrack::host {

namespace {
bool is_off(const YAML::Node& n) { return n.IsScalar() && (n.Scalar() == "off" || n.Scalar() == "false"); }
}  // namespace

Status SceneParser::parse_physics(const YAML::Node& n, SimFrameSpec* sim) const {
  auto preset_of = [&](const YAML::Node& node) -> Status {
    std::string name;
    LFTRACK_RETURN_IF_ERROR(one_of(node, "sim.physics preset", sim::physics_preset_names(), &name));
    sim->physics = *sim::physics_preset(name);
    sim->physics_name = name;
    return {};
  };
  if (n.IsScalar()) return preset_of(n);
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "sim.physics", {"preset", "spectrum", "scatter", "detector", "anatomy"}));
  sim->physics = {};
  sim->physics_name = "ideal";
  if (n["preset"]) LFTRACK_RETURN_IF_ERROR(preset_of(n["preset"]));
  auto in_range = [&](const YAML::Node& node, const std::string& what, double lo, double hi, double* out) -> Status {
    LFTRACK_RETURN_IF_ERROR(number(node, what, out));
    if (*out < lo || *out > hi)
      return error(node, what + " must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return {};
  };
  auto flag = [&](const YAML::Node& node, const std::string& what, bool* out) -> Status {
    if (!node.IsScalar() || (node.Scalar() != "true" && node.Scalar() != "false"))
      return error(node, what + " must be true or false");
    *out = node.Scalar() == "true";
    return {};
  };
  bool changed = false;
  if (const YAML::Node s = n["spectrum"]) {
    changed = true;
    if (is_off(s)) {
      sim->physics.spectrum.reset();
    } else {
      LFTRACK_RETURN_IF_ERROR(check_keys(s, "sim.physics.spectrum", {"kvp", "filtration_mm_al", "ct_effective_kev"}));
      sim::BeamSpec b = sim->physics.spectrum.value_or(sim::clinical_beam());
      if (s["kvp"]) LFTRACK_RETURN_IF_ERROR(in_range(s["kvp"], "sim.physics.spectrum.kvp", 40, 150, &b.spectrum.kvp));
      if (s["filtration_mm_al"])
        LFTRACK_RETURN_IF_ERROR(in_range(s["filtration_mm_al"], "sim.physics.spectrum.filtration_mm_al", 0, 20,
                                         &b.spectrum.filtration_mm_al));
      if (s["ct_effective_kev"])
        LFTRACK_RETURN_IF_ERROR(
            in_range(s["ct_effective_kev"], "sim.physics.spectrum.ct_effective_kev", 30, 150, &b.ct_effective_kev));
      sim->physics.spectrum = b;
    }
  }
  if (const YAML::Node s = n["scatter"]) {
    changed = true;
    if (is_off(s)) {
      sim->physics.scatter.reset();
    } else {
      LFTRACK_RETURN_IF_ERROR(check_keys(s, "sim.physics.scatter",
                                         {"spr_per_cm", "kernel_sigma_mm", "grid", "grid_primary_transmission",
                                          "grid_scatter_transmission"}));
      sim::ScatterSpec c = sim->physics.scatter.value_or(sim::clinical_scatter());
      if (s["spr_per_cm"])
        LFTRACK_RETURN_IF_ERROR(in_range(s["spr_per_cm"], "sim.physics.scatter.spr_per_cm", 0, 1, &c.spr_per_cm));
      if (s["kernel_sigma_mm"])
        LFTRACK_RETURN_IF_ERROR(
            in_range(s["kernel_sigma_mm"], "sim.physics.scatter.kernel_sigma_mm", 0.1, 500, &c.kernel_sigma_mm));
      if (s["grid"]) LFTRACK_RETURN_IF_ERROR(flag(s["grid"], "sim.physics.scatter.grid", &c.grid));
      if (s["grid_primary_transmission"])
        LFTRACK_RETURN_IF_ERROR(in_range(s["grid_primary_transmission"], "sim.physics.scatter.grid_primary_transmission",
                                         0.01, 1, &c.grid_primary_transmission));
      if (s["grid_scatter_transmission"])
        LFTRACK_RETURN_IF_ERROR(in_range(s["grid_scatter_transmission"], "sim.physics.scatter.grid_scatter_transmission",
                                         0, 1, &c.grid_scatter_transmission));
      if (auto st = sim::check_scatter_spec(c); !st.ok()) return error(s, st.message());
      sim->physics.scatter = c;
    }
  }
  if (const YAML::Node s = n["detector"]) {
    changed = true;
    if (is_off(s)) {
      sim->physics.detector.reset();
    } else {
      LFTRACK_RETURN_IF_ERROR(check_keys(s, "sim.physics.detector",
                                         {"glare_fraction", "glare_sigma_mm", "lag_fraction", "gain_smooth_rms",
                                          "gain_pixel_rms", "defective_pixel_fraction", "defective_lines",
                                          "heel_gradient"}));
      sim::DetectorEffectsSpec d = sim->physics.detector.value_or(sim::clinical_detector());
      const std::string w = "sim.physics.detector.";
      if (s["glare_fraction"]) LFTRACK_RETURN_IF_ERROR(in_range(s["glare_fraction"], w + "glare_fraction", 0, 0.5, &d.glare_fraction));
      if (s["glare_sigma_mm"]) LFTRACK_RETURN_IF_ERROR(in_range(s["glare_sigma_mm"], w + "glare_sigma_mm", 0.01, 100, &d.glare_sigma_mm));
      if (s["lag_fraction"]) LFTRACK_RETURN_IF_ERROR(in_range(s["lag_fraction"], w + "lag_fraction", 0, 0.5, &d.lag_fraction));
      if (s["gain_smooth_rms"]) LFTRACK_RETURN_IF_ERROR(in_range(s["gain_smooth_rms"], w + "gain_smooth_rms", 0, 0.2, &d.gain_smooth_rms));
      if (s["gain_pixel_rms"]) LFTRACK_RETURN_IF_ERROR(in_range(s["gain_pixel_rms"], w + "gain_pixel_rms", 0, 0.2, &d.gain_pixel_rms));
      if (s["defective_pixel_fraction"])
        LFTRACK_RETURN_IF_ERROR(in_range(s["defective_pixel_fraction"], w + "defective_pixel_fraction", 0, 0.1,
                                         &d.defective_pixel_fraction));
      if (s["defective_lines"]) {
        long lines = 0;
        LFTRACK_RETURN_IF_ERROR(integer(s["defective_lines"], w + "defective_lines", 0, 8, &lines));
        d.defective_lines = int(lines);
      }
      if (s["heel_gradient"]) LFTRACK_RETURN_IF_ERROR(in_range(s["heel_gradient"], w + "heel_gradient", -0.5, 0.5, &d.heel_gradient));
      sim->physics.detector = d;
    }
  }
  if (const YAML::Node s = n["anatomy"]) {
    changed = true;
    if (is_off(s)) {
      sim->physics.anatomy.reset();
    } else {
      LFTRACK_RETURN_IF_ERROR(check_keys(s, "sim.physics.anatomy",
                                         {"soft_tissue_mm", "soft_tissue_scale_mm", "ramp_mm",
                                          "adjacent_translation_mm", "adjacent_rotation_deg", "disc_mm",
                                          "breathing_mm", "target_size_mm", "seed"}));
      sim::AnatomySpec a = sim->physics.anatomy.value_or(sim::clinical_anatomy());
      const std::string w = "sim.physics.anatomy.";
      if (s["soft_tissue_mm"]) LFTRACK_RETURN_IF_ERROR(in_range(s["soft_tissue_mm"], w + "soft_tissue_mm", 0, 30, &a.soft_tissue_mm));
      if (s["soft_tissue_scale_mm"])
        LFTRACK_RETURN_IF_ERROR(in_range(s["soft_tissue_scale_mm"], w + "soft_tissue_scale_mm", 10, 1000, &a.soft_tissue_scale_mm));
      if (s["ramp_mm"]) LFTRACK_RETURN_IF_ERROR(in_range(s["ramp_mm"], w + "ramp_mm", 1, 500, &a.ramp_mm));
      if (s["adjacent_translation_mm"])
        LFTRACK_RETURN_IF_ERROR(in_range(s["adjacent_translation_mm"], w + "adjacent_translation_mm", 0, 10,
                                         &a.adjacent_translation_mm));
      if (s["adjacent_rotation_deg"])
        LFTRACK_RETURN_IF_ERROR(in_range(s["adjacent_rotation_deg"], w + "adjacent_rotation_deg", 0, 10,
                                         &a.adjacent_rotation_deg));
      if (s["disc_mm"]) LFTRACK_RETURN_IF_ERROR(in_range(s["disc_mm"], w + "disc_mm", 1, 100, &a.disc_mm));
      if (s["breathing_mm"]) LFTRACK_RETURN_IF_ERROR(in_range(s["breathing_mm"], w + "breathing_mm", 0, 40, &a.breathing_mm));
      if (s["target_size_mm"]) {
        LFTRACK_RETURN_IF_ERROR(vec3(s["target_size_mm"], w + "target_size_mm", &a.target_size_mm));
        for (int k = 0; k < 3; ++k)
          if (!(a.target_size_mm[k] >= 1 && a.target_size_mm[k] <= 1000))
            return error(s["target_size_mm"], w + "target_size_mm must be in [1, 1000] mm per axis");
      }
      if (s["seed"]) {
        long seed = 0;
        LFTRACK_RETURN_IF_ERROR(integer(s["seed"], w + "seed", 0, 2147483647L, &seed));
        a.seed = std::uint64_t(seed);
      }
      sim->physics.anatomy = a;
    }
  }
  if (changed) sim->physics_name = sim->physics.ideal() ? "ideal" : "custom";
  if (auto st = sim::check_physics(sim->physics); !st.ok()) return error(n, st.message());
  return {};
}

}  // namespace lftrack::host
