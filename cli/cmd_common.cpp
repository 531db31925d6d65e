#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "cli_commands.hpp"
#include "lftrack/session/scene_registration.hpp"

namespace lftrack::cli {

using session::load_light_fields;
using session::load_scene;
using session::make_scene_renderer;
using session::prepare_scene;
using session::PreparedScene;

CLI::Validator not_empty() {
  return CLI::Validator(
      [](const std::string& text) -> std::string { return text.empty() ? "an empty value names nothing" : ""; },
      "");
}

CLI::Validator seed_value() {
  return CLI::Validator(
      [](const std::string& text) -> std::string {
        const bool digits = !text.empty() && text.size() <= 20 &&
                            text.find_first_not_of("0123456789") == std::string::npos;
        errno = 0;
        if (digits) (void)std::strtoull(text.c_str(), nullptr, 10);
        if (!digits || errno == ERANGE) return "'" + text + "' is not a seed (a whole number from 0 to 18446744073709551615)";
        return {};
      },
      "SEED");
}

CLI::Validator finite_in(double lo, double hi, bool lo_open, bool hi_open) {
  std::ostringstream range;
  range << (lo_open ? "(" : "[") << lo << ", " << hi << (hi_open ? ")" : "]");
  return CLI::Validator(
      [lo, hi, lo_open, hi_open, range = range.str()](const std::string& text) -> std::string {
        char* end = nullptr;
        const double v = std::strtod(text.c_str(), &end);
        if (text.empty() || end != text.c_str() + text.size()) return "'" + text + "' is not a number";
        if (!std::isfinite(v)) return "'" + text + "' is not finite";
        if (v < lo || v > hi || (lo_open && v == lo) || (hi_open && v == hi))
          return "'" + text + "' is outside " + range;
        return {};
      },
      "NUMBER in " + range.str());
}

void add_scene_options(CLI::App* app, SceneOptions* o) {
  app->add_option("--scene", o->scene, "Scene file, or builtin:phantom")->capture_default_str();
  app->add_option("--ct", o->ct, "CT to use instead of the scene's (DICOM folder or .nii/.nii.gz)");
  app->add_option("--threads", o->threads, "Worker threads (0: all cores)")->check(CLI::Range(0, 256));
}

Result<PreparedScene> load_prepared_scene(const SceneOptions& options, tracking::ThreadPool* pool) {
  auto scene = load_scene(options.scene);
  if (!scene.ok()) return scene.status();
  return prepare_scene(*scene, options.ct, pool);
}

Result<StudyPhysics> study_physics(const std::string& option, const PreparedScene* scene) {
  StudyPhysics out;
  if (option == "scene") {
    if (scene) {
      out.physics = scene->scene.sim.physics;
      out.name = scene->scene.sim.physics_name;
    }
    return out;
  }
  auto preset = sim_spec::physics_preset(option);
  if (!preset.ok()) return invalid_argument("--physics: ideal, clinical or scene (the scene's sim.physics)");
  out.physics = *preset;
  out.name = option;
  return out;
}

Result<std::pair<int, int>> parse_shard(const std::string& text) {
  const Status bad = invalid_argument("--shard '" + text + "': expected k/n with 1 <= k <= n <= 10000, e.g. 3/8");
  const auto slash = text.find('/');
  if (slash == std::string::npos || slash == 0 || slash + 1 == text.size() || slash > 5 || text.size() - slash > 6)
    return bad;
  for (std::size_t i = 0; i < text.size(); ++i)
    if (i != slash && !std::isdigit(static_cast<unsigned char>(text[i]))) return bad;
  const int k = std::stoi(text.substr(0, slash)), n = std::stoi(text.substr(slash + 1));
  if (n < 1 || k < 1 || k > n || n > 10000) return bad;
  return std::make_pair(k, n);
}

Result<bool> study_light_fields(const PreparedScene& scene, const std::string& study, const std::string& renderer,
                                const std::string& lf_dir, bool build, bool prebuilt, tracking::ThreadPool* pool) {
  if (renderer != "lightfield") return build;  // nothing to build or map
  if (build) {
    auto built = make_scene_renderer(scene, renderer, lf_dir, pool);
    if (!built.ok()) return built.status();
    std::printf("light fields ready in %s\n", lf_dir.c_str());
    return true;
  }
  if (prebuilt) {
    auto fields = load_light_fields(scene, lf_dir);
    if (!fields.ok())
      return failed_precondition("light fields in " + lf_dir + " are not built (" + fields.status().message() +
                                 "); the study's field job builds them: `lftrack study " + study +
                                 " --build-fields --lf-dir DIR`");
  }
  return false;
}

}  // namespace lftrack::cli
