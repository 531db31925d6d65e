// The scene's sim.physics section (issue 21): presets, per-part changes, and refusals located at
// the scene's line.
#include <gtest/gtest.h>

#include "lftrack/session/scene.hpp"

namespace lftrack::session {
namespace {

const std::string kScene = R"(version: 1
ct:
  path: ct_folder
roi:
  centre_mm: [0, 0, 0]
detectors:
  - name: A
    rows: 64
    cols: 64
    pitch_mm: 0.4
    isocentric:
      source_direction: [0, -1, 0]
      up: [0, 0, 1]
      source_to_isocentre_mm: 1000
      source_to_detector_mm: 1500
sim:
)";

Result<Scene> with_physics(const std::string& physics) {
  return parse_scene(kScene + "  physics:" + physics, "room.yaml", "/scenes");
}

TEST(ScenePhysics, IdealByDefaultAndPresetsByName) {
  auto plain = parse_scene(kScene.substr(0, kScene.size() - 5), "room.yaml", "/scenes");
  ASSERT_TRUE(plain.ok()) << plain.status().message();
  EXPECT_TRUE(plain->sim.physics.ideal());
  EXPECT_EQ(plain->sim.physics_name, "ideal");
  auto clinical = with_physics(" clinical\n");
  ASSERT_TRUE(clinical.ok()) << clinical.status().message();
  EXPECT_EQ(clinical->sim.physics_name, "clinical");
  ASSERT_TRUE(clinical->sim.physics.spectrum && clinical->sim.physics.scatter && clinical->sim.physics.detector &&
              clinical->sim.physics.anatomy);
  EXPECT_DOUBLE_EQ(clinical->sim.physics.spectrum->spectrum.kvp, 120);
  EXPECT_TRUE(clinical->sim.physics.scatter->grid);
}

TEST(ScenePhysics, PartsChangeOnAPresetAndSwitchOff) {
  auto s = with_physics(R"(
    preset: clinical
    spectrum: {kvp: 100}
    scatter: off
    anatomy: {breathing_mm: 8, target_size_mm: [50, 50, 25], seed: 4}
)");
  ASSERT_TRUE(s.ok()) << s.status().message();
  const auto& p = s->sim.physics;
  EXPECT_EQ(s->sim.physics_name, "custom");
  EXPECT_DOUBLE_EQ(p.spectrum->spectrum.kvp, 100);
  EXPECT_DOUBLE_EQ(p.spectrum->spectrum.filtration_mm_al, 2.5);  // the preset's
  EXPECT_FALSE(p.scatter.has_value());
  EXPECT_DOUBLE_EQ(p.anatomy->breathing_mm, 8);
  EXPECT_DOUBLE_EQ(p.anatomy->soft_tissue_mm, 3);
  EXPECT_EQ(p.anatomy->seed, 4u);
  EXPECT_DOUBLE_EQ(p.anatomy->target_size_mm.z(), 25);
  // A part on an ideal base starts from the clinical values of that part alone.
  auto one = with_physics("\n    detector: {lag_fraction: 0.05}\n");
  ASSERT_TRUE(one.ok()) << one.status().message();
  EXPECT_FALSE(one->sim.physics.spectrum.has_value());
  EXPECT_DOUBLE_EQ(one->sim.physics.detector->lag_fraction, 0.05);
  EXPECT_DOUBLE_EQ(one->sim.physics.detector->glare_fraction, 0.05);
}

TEST(ScenePhysics, BadValuesAreRefusedAtTheirLine) {
  struct Case {
    std::string physics, says;
  };
  for (const Case& c : std::vector<Case>{
           {" realistic\n", "unknown sim.physics preset 'realistic'"},
           {"\n    spectrum: {kvp: .nan}\n", "must be finite"},
           {"\n    spectrum: {kvp: 1e12}\n", "kvp must be in"},
           {"\n    spectrum: {kvp: -1}\n", "kvp must be in"},
           {"\n    scatter: {spr_per_cm: 0, grid_scatter_transmission: 0.9, grid_primary_transmission: 0.5}\n",
            "grid transmissions"},
           {"\n    detector: {defective_lines: 100}\n", "defective_lines"},
           {"\n    detector: {lag: 0.1}\n", "unknown key 'lag'"},
           {"\n    anatomy: {target_size_mm: [0, 50, 50]}\n", "target_size_mm"},
           {"\n    anatomy: {soft_tissue_mm: .inf}\n", "must be finite"},
           {"\n    anatomy: [1, 2]\n", "must be a mapping"},
           {"\n    preset: clinical\n    preset: ideal\n", "appears twice"},
       }) {
    auto s = with_physics(c.physics);
    ASSERT_FALSE(s.ok()) << c.physics;
    EXPECT_NE(s.status().message().find(c.says), std::string::npos) << s.status().message();
    EXPECT_NE(s.status().message().find("room.yaml:"), std::string::npos) << s.status().message();
  }
}

}  // namespace
}  // namespace lftrack::session
