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
// A part named as a mapping starts from the clinical preset's values of that part. The ranges
// are the spec's own range checks (sim_spec::check_physics), reported at the part's line.
#include <type_traits>

#include "scene_yaml.hpp"

namespace lftrack::session {

namespace {

bool is_off(const YAML::Node& n) { return n.IsScalar() && (n.Scalar() == "off" || n.Scalar() == "false"); }

// A part's numeric keys and where each goes.
using NumberFields = std::vector<std::pair<std::string, double*>>;

}  // namespace

Status SceneParser::parse_physics(const YAML::Node& n, SimFrameSpec* sim) const {
  auto preset_of = [&](const YAML::Node& node) -> Status {
    std::string name;
    LFTRACK_RETURN_IF_ERROR(one_of(node, "sim.physics preset", sim_spec::physics_preset_names(), &name));
    sim->physics = *sim_spec::physics_preset(name);
    sim->physics_name = name;
    return {};
  };
  if (n.IsScalar()) return preset_of(n);
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "sim.physics", {"preset", "spectrum", "scatter", "detector", "anatomy"}));
  sim->physics = {};
  sim->physics_name = "ideal";
  if (n["preset"]) LFTRACK_RETURN_IF_ERROR(preset_of(n["preset"]));

  // Reads one part: `off`, or a mapping of `numbers` plus the `other` keys (read by `read_other`).
  // Ranges are the part's own checks (sim_spec::check_physics), reported at the part's line.
  auto part = [&](const char* name, auto* slot, const auto& clinical, auto fields_of,
                  const std::set<std::string>& other, auto read_other) -> Status {
    const YAML::Node s = n[name];
    if (!s) return {};
    if (is_off(s)) {
      slot->reset();
      return {};
    }
    const std::string what = std::string("sim.physics.") + name;
    auto value = slot->value_or(clinical);
    const NumberFields numbers = fields_of(value);
    std::set<std::string> allowed = other;
    for (const auto& [key, out] : numbers) allowed.insert(key);
    LFTRACK_RETURN_IF_ERROR(check_keys(s, what, allowed));
    for (const auto& [key, out] : numbers)
      if (s[key]) LFTRACK_RETURN_IF_ERROR(number(s[key], what + "." + key, out));
    LFTRACK_RETURN_IF_ERROR(read_other(s, what, value));
    *slot = value;
    sim_spec::XrayPhysicsSpec alone;
    if constexpr (std::is_same_v<decltype(value), sim_spec::BeamSpec>) alone.spectrum = value;
    if constexpr (std::is_same_v<decltype(value), sim_spec::ScatterSpec>) alone.scatter = value;
    if constexpr (std::is_same_v<decltype(value), sim_spec::DetectorEffectsSpec>) alone.detector = value;
    if constexpr (std::is_same_v<decltype(value), sim_spec::AnatomySpec>) alone.anatomy = value;
    if (auto st = sim_spec::check_physics(alone); !st.ok()) return error(s, st.message());
    return {};
  };
  auto nothing_else = [](const YAML::Node&, const std::string&, auto&) { return Status(); };

  if (Status st = part(
          "spectrum", &sim->physics.spectrum, sim_spec::clinical_beam(),
          [](sim_spec::BeamSpec& b) {
            return NumberFields{{"kvp", &b.spectrum.kvp},
                                {"filtration_mm_al", &b.spectrum.filtration_mm_al},
                                {"ct_effective_kev", &b.ct_effective_kev}};
          },
          {}, nothing_else);
      !st.ok())
    return st;
  if (Status st = part(
          "scatter", &sim->physics.scatter, sim_spec::clinical_scatter(),
          [](sim_spec::ScatterSpec& c) {
            return NumberFields{{"spr_per_cm", &c.spr_per_cm},
                                {"kernel_sigma_mm", &c.kernel_sigma_mm},
                                {"grid_primary_transmission", &c.grid_primary_transmission},
                                {"grid_scatter_transmission", &c.grid_scatter_transmission}};
          },
          {"grid"},
          [&](const YAML::Node& s, const std::string& what, sim_spec::ScatterSpec& c) -> Status {
            if (!s["grid"]) return {};
            if (!s["grid"].IsScalar() || (s["grid"].Scalar() != "true" && s["grid"].Scalar() != "false"))
              return error(s["grid"], what + ".grid must be true or false");
            c.grid = s["grid"].Scalar() == "true";
            return {};
          });
      !st.ok())
    return st;
  if (Status st = part(
          "detector", &sim->physics.detector, sim_spec::clinical_detector(),
          [](sim_spec::DetectorEffectsSpec& d) {
            return NumberFields{{"glare_fraction", &d.glare_fraction},
                                {"glare_sigma_mm", &d.glare_sigma_mm},
                                {"lag_fraction", &d.lag_fraction},
                                {"gain_smooth_rms", &d.gain_smooth_rms},
                                {"gain_pixel_rms", &d.gain_pixel_rms},
                                {"defective_pixel_fraction", &d.defective_pixel_fraction},
                                {"heel_gradient", &d.heel_gradient}};
          },
          {"defective_lines"},
          [&](const YAML::Node& s, const std::string& what, sim_spec::DetectorEffectsSpec& d) -> Status {
            if (!s["defective_lines"]) return {};
            long lines = 0;
            LFTRACK_RETURN_IF_ERROR(
                integer(s["defective_lines"], what + ".defective_lines", -1000000, 1000000, &lines));
            d.defective_lines = int(lines);
            return {};
          });
      !st.ok())
    return st;
  if (Status st = part(
          "anatomy", &sim->physics.anatomy, sim_spec::clinical_anatomy(),
          [](sim_spec::AnatomySpec& a) {
            return NumberFields{{"soft_tissue_mm", &a.soft_tissue_mm},
                                {"soft_tissue_scale_mm", &a.soft_tissue_scale_mm},
                                {"ramp_mm", &a.ramp_mm},
                                {"adjacent_translation_mm", &a.adjacent_translation_mm},
                                {"adjacent_rotation_deg", &a.adjacent_rotation_deg},
                                {"disc_mm", &a.disc_mm},
                                {"breathing_mm", &a.breathing_mm}};
          },
          {"target_size_mm", "seed"},
          [&](const YAML::Node& s, const std::string& what, sim_spec::AnatomySpec& a) -> Status {
            if (s["target_size_mm"])
              LFTRACK_RETURN_IF_ERROR(vec3(s["target_size_mm"], what + ".target_size_mm", &a.target_size_mm));
            if (s["seed"]) {
              long seed = 0;
              LFTRACK_RETURN_IF_ERROR(integer(s["seed"], what + ".seed", 0, 2147483647L, &seed));
              a.seed = std::uint64_t(seed);
            }
            return {};
          });
      !st.ok())
    return st;
  if (n["spectrum"] || n["scatter"] || n["detector"] || n["anatomy"])
    sim->physics_name = sim->physics.ideal() ? "ideal" : "custom";
  return {};
}

}  // namespace lftrack::session
