#include "cli_commands.hpp"

namespace lftrack::host::cli {

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
