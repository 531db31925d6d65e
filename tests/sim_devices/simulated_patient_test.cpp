// The simulated patient (simulated_patient.cpp): with realistic physics and sim.renderer
// lightfield (issue 51), the water and bone it is imaged through are rendered from light fields
// of their own, built once into <light-field folder>/sim-frames/{water,bone} and loaded after,
// and their line integrals are those Siddon gives through the same volumes.

#include "lftrack/sim_devices/simulated_patient.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <map>

#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/image_metrics.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::sim_devices {

using session::load_scene;
using session::prepare_scene;
using session::PreparedScene;

namespace {

namespace fs = std::filesystem;

std::map<std::string, fs::file_time_type> files_of(const fs::path& dir) {
  std::map<std::string, fs::file_time_type> out;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    out[it->path().filename().string()] = it->last_write_time();
  return out;
}

// The built-in phantom with the clinical preset and small frame fields (built in seconds).
Result<PreparedScene> clinical_phantom(const std::string& sim_renderer, tracking::ThreadPool* pool) {
  auto scene = load_scene("builtin:phantom");
  if (!scene.ok()) return scene.status();
  auto physics = sim_spec::physics_preset("clinical");
  if (!physics.ok()) return physics.status();
  scene->sim.physics = *physics;
  scene->sim.physics_name = "clinical";
  scene->sim.renderer = sim_renderer;
  scene->sim.light_field.resolution = {8, 8, 192, 192};
  return prepare_scene(*scene, "", pool);
}

TEST(SimulatedPatient, RealisticPhysicsRendersWaterAndBoneFromLightFieldsBuiltOnce) {
  tracking::ThreadPool pool(2);
  auto fields = clinical_phantom("lightfield", &pool);
  ASSERT_TRUE(fields.ok()) << fields.status().message();
  auto exact = clinical_phantom("siddon", &pool);
  ASSERT_TRUE(exact.ok()) << exact.status().message();
  test::TempDir dir;
  auto from_fields = make_scene_patient(*fields, dir.path(), &pool);
  ASSERT_TRUE(from_fields.ok()) << from_fields.status().message();
  ASSERT_TRUE(*from_fields);
  ASSERT_TRUE((*from_fields)->water_renderer && (*from_fields)->bone_renderer);
  EXPECT_FALSE((*from_fields)->attenuation_renderer) << "a spectrum images water and bone";
  // The loop's patient renders the rest of each detector too, by Siddon (the fields cover the ROI).
  ASSERT_TRUE((*from_fields)->surround_water && (*from_fields)->surround_bone);
  EXPECT_EQ((*from_fields)->surround_water->name(), "siddon");
  auto without = make_simulated_patient(*fields, fields->scene.sim.physics, 1, &pool);
  ASSERT_TRUE(without.ok()) << without.status().message();
  EXPECT_FALSE(without->surround_water || without->surround_bone) << "made only when asked for";
  const auto water = files_of(dir.path() / "sim-frames" / "water");
  const auto bone = files_of(dir.path() / "sim-frames" / "bone");
  EXPECT_EQ(water.size(), fields->scene.detectors.size()) << "one field per view";
  EXPECT_EQ(bone.size(), fields->scene.detectors.size());
  // A second patient of the same scene loads the fields: not one is written again.
  auto again = make_scene_patient(*fields, dir.path(), &pool);
  ASSERT_TRUE(again.ok()) << again.status().message();
  EXPECT_EQ(files_of(dir.path() / "sim-frames" / "water"), water);
  EXPECT_EQ(files_of(dir.path() / "sim-frames" / "bone"), bone);

  auto siddon = make_scene_patient(*exact, dir.path(), &pool);
  ASSERT_TRUE(siddon.ok()) << siddon.status().message();
  ASSERT_TRUE(*siddon && (*siddon)->water_renderer && (*siddon)->bone_renderer);
  EXPECT_EQ((*siddon)->water_renderer->name(), "siddon");
  // The same anatomy draw (the scene's seed) through both: the line integrals over each ROI
  // window agree, at the nominal pose and 3 mm / 2 degrees off it.
  tracking::Pose moved = fields->nominal_T_room_from_ct;
  moved.translation() += Eigen::Vector3d(3, -2, 1);
  moved.linear() =
      (Eigen::AngleAxisd(tracking::deg_to_rad(2), Eigen::Vector3d::UnitZ()) * moved.linear()).eval();
  for (const tracking::Pose& pose : {fields->nominal_T_room_from_ct, moved}) {
    for (std::size_t v = 0; v < fields->scene.detectors.size(); ++v) {
      const auto& view = fields->scene.detectors[v].view;
      const tracking::PixelWindow& w = fields->roi_windows[v];
      for (const auto& [material, ours, theirs] :
           {std::tuple{"water", (*from_fields)->water_renderer, (*siddon)->water_renderer},
            std::tuple{"bone", (*from_fields)->bone_renderer, (*siddon)->bone_renderer}}) {
        tracking::Image<float> a(w.rows, w.cols), b(w.rows, w.cols);
        ASSERT_TRUE(ours->render(pose, view, w, a.view()).ok());
        ASSERT_TRUE(theirs->render(pose, view, w, b.view()).ok());
        EXPECT_GT(tracking::normalized_cross_correlation(b.view(), a.view()), 0.99)
            << material << ", view " << view.name;
      }
    }
  }
}

TEST(SimulatedPatient, IdealPhysicsHasNoPatientWhateverTheRenderer) {
  tracking::ThreadPool pool(2);
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok());
  scene->sim.renderer = "lightfield";
  auto p = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(p.ok()) << p.status().message();
  test::TempDir dir;
  auto patient = make_scene_patient(*p, dir.path(), &pool);
  ASSERT_TRUE(patient.ok()) << patient.status().message();
  EXPECT_FALSE(*patient) << "ideal frames render the world anatomy (make_sim_frame_renderer)";
  EXPECT_FALSE(fs::exists(dir.path() / "sim-frames")) << "nothing is built for a patient there is not";
}

}  // namespace
}  // namespace lftrack::sim_devices
