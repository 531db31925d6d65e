#include <cmath>
#include <cstdlib>
#include <sstream>

#include "cli_commands.hpp"

namespace lftrack::host::cli {

CLI::Validator finite_in(double lo, double hi, bool lo_open) {
  std::ostringstream range;
  range << (lo_open ? "(" : "[") << lo << ", " << hi << "]";
  return CLI::Validator(
      [lo, hi, lo_open, range = range.str()](const std::string& text) -> std::string {
        char* end = nullptr;
        const double v = std::strtod(text.c_str(), &end);
        if (text.empty() || end != text.c_str() + text.size()) return "'" + text + "' is not a number";
        if (!std::isfinite(v)) return "'" + text + "' is not finite";
        if (v < lo || v > hi || (lo_open && v == lo)) return "'" + text + "' is outside " + range;
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

}  // namespace lftrack::host::cli
