// The scene keys that configure the loop (loop, actuator, motion). (Moved from the loop's parts
// test.)

#include <gtest/gtest.h>

#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_verdict.hpp"

namespace lftrack::session {

using loop::judges_view_shift;
namespace {

TEST(SceneLoopKeys, ParseAndRejectWithLocation) {
  const std::string base = *builtin_scene_text(kBuiltinPhantom);
  auto scene = parse_scene(base, "b.yaml", ".");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->loop.period_ms, 100);
  EXPECT_EQ(scene->actuator.type, "virtual");
  EXPECT_NEAR(scene->motion.motion.breathing_amplitude(2), 4.5, 1e-12);
  EXPECT_NEAR(scene->motion.setup_error(3), tracking::deg_to_rad(1.0), 1e-12);
  EXPECT_EQ(scene->sim.renderer, "lightfield");
  EXPECT_FALSE(scene->loop.realtime.enforce);
  const auto fails = [&](const std::string& extra, const std::string& expect) {
    auto s = parse_scene(base + extra, "b.yaml", ".");
    ASSERT_FALSE(s.ok()) << extra;
    EXPECT_NE(s.status().message().find(expect), std::string::npos) << s.status().message();
  };
  fails("shifts: []\n", "unknown key 'shifts'");
  std::string budget = base;
  budget.replace(budget.find("registration_budget_ms: 50"), 26, "registration_budget_ms: 90");
  auto s = parse_scene(budget, "b.yaml", ".");
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("must fit in period_ms"), std::string::npos) << s.status().message();
  std::string mode = base;
  mode.replace(mode.find("mode: ignore"), 12, "mode: maybe");
  s = parse_scene(mode, "b.yaml", ".");
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("b.yaml:"), std::string::npos);
  std::string actuator = base;
  actuator.replace(actuator.find("type: virtual"), 13, "type: hydraulic");
  EXPECT_FALSE(parse_scene(actuator, "b.yaml", ".").ok());
}

// The built-in scene with `keys` (indented lines) added at the top of its `section`.
Result<Scene> with_keys(const std::string& section, const std::string& keys) {
  std::string text = *builtin_scene_text(kBuiltinPhantom);
  const std::string head = section + ":\n";
  text.replace(text.find(head), head.size(), head + keys);
  return parse_scene(text, "b.yaml", ".");
}

// loop.predict_rotations (false: only translations are extrapolated).
TEST(SceneLoopKeys, RotationsArePredictedOnlyWhereASceneAsks) {
  auto scene = parse_scene(*builtin_scene_text(kBuiltinPhantom), "b.yaml", ".");
  ASSERT_TRUE(scene.ok());
  EXPECT_FALSE(scene->loop.predict_rotations);
  auto set = with_keys("loop", "  predict_rotations: true\n");
  ASSERT_TRUE(set.ok()) << set.status().message();
  EXPECT_TRUE(set->loop.predict_rotations);
  for (const char* bad : {"  predict_rotations: yes\n", "  predict_rotations: 2\n", "  predict_rotations: ''\n"}) {
    auto refused = with_keys("loop", bad);
    EXPECT_FALSE(refused.ok()) << bad;
  }
}

// loop.judge_tracking (unset: follow the scene's commissioning).
TEST(SceneLoopKeys, TheVerdictOnTrackingCycles) {
  const std::string base = *builtin_scene_text(kBuiltinPhantom);
  auto scene = parse_scene(base, "b.yaml", ".");
  ASSERT_TRUE(scene.ok());
  EXPECT_FALSE(scene->loop.judge_tracking.has_value());
  const auto with = [](const std::string& keys) { return with_keys("loop", keys); };
  auto set = with("  judge_tracking: true\n");
  ASSERT_TRUE(set.ok()) << set.status().message();
  EXPECT_EQ(set->loop.judge_tracking, std::optional<bool>(true));
  for (const char* bad : {"  judge_tracking: yes\n", "  judge_tracking: 1\n", "  judge_tracking: ''\n",
                          "  judge_tracking: [true]\n", "  verdict_check_every: 5\n"}) {
    auto refused = with(bad);
    EXPECT_FALSE(refused.ok()) << bad;
    if (!refused.ok()) {
      EXPECT_NE(refused.status().message().find("b.yaml:"), std::string::npos) << bad;
    }
  }
}

// safety's keys for the verdict's edge band and view check (registration_verdict.hpp).
TEST(SceneLoopKeys, TheVerdictsEdgeBandAndViewCheck) {
  const std::string base = *builtin_scene_text(kBuiltinPhantom);
  auto scene = parse_scene(base, "b.yaml", ".");
  ASSERT_TRUE(scene.ok());
  EXPECT_DOUBLE_EQ(scene->verdict_checks.envelope_edge_mm, 0.5);
  EXPECT_DOUBLE_EQ(scene->verdict_checks.envelope_edge_deg, 0);
  EXPECT_DOUBLE_EQ(scene->verdict_checks.max_view_shift_mm, 1.0);
  EXPECT_EQ(scene->verdict_checks.view_check_every, 10);
  auto limits = verdict_limits(*scene, "mi");
  ASSERT_TRUE(limits.ok());
  EXPECT_DOUBLE_EQ(limits->envelope_edge_mm, 0.5);
  EXPECT_TRUE(judges_view_shift(*limits));
  const auto with = [](const std::string& keys) { return with_keys("safety", keys); };
  // Unset, the band is the envelope's outer 5 %: a small envelope keeps most of itself.
  std::string small = base;
  const std::string ten = "envelope:\n  translation_mm: 10\n";
  small.replace(small.find(ten), ten.size(), "envelope:\n  translation_mm: 1\n");
  auto small_scene = parse_scene(small, "b.yaml", ".");
  ASSERT_TRUE(small_scene.ok()) << small_scene.status().message();
  EXPECT_NEAR(small_scene->verdict_checks.envelope_edge_mm, 0.05, 1e-12);
  auto set = with("  envelope_edge_mm: 1.5\n  envelope_edge_deg: 0.25\n  max_view_shift_mm: 0\n  view_check_every: 0\n");
  ASSERT_TRUE(set.ok()) << set.status().message();
  EXPECT_DOUBLE_EQ(set->verdict_checks.envelope_edge_mm, 1.5);
  EXPECT_DOUBLE_EQ(set->verdict_checks.envelope_edge_deg, 0.25);
  EXPECT_EQ(set->verdict_checks.view_check_every, 0);
  auto off = verdict_limits(*set, "mi");
  ASSERT_TRUE(off.ok());
  EXPECT_FALSE(judges_view_shift(*off)) << "max_view_shift_mm: 0 turns the view check off";
  EXPECT_DOUBLE_EQ(off->envelope_edge_deg, 0.25);
  for (const char* bad :
       {"  envelope_edge_mm: -0.1\n", "  envelope_edge_mm: 10\n", "  envelope_edge_mm: .nan\n",
        "  envelope_edge_mm: 1e12\n", "  envelope_edge_deg: 5\n", "  envelope_edge_deg: -1\n",
        "  max_view_shift_mm: -1\n", "  max_view_shift_mm: .inf\n", "  max_view_shift_mm: 21\n",
        "  max_view_shift_mm: one\n", "  view_check_every: -1\n", "  view_check_every: 2.5\n",
        "  view_check_every: 1e12\n"}) {
    auto refused = with(bad);
    EXPECT_FALSE(refused.ok()) << bad;
    if (!refused.ok()) {
      EXPECT_NE(refused.status().message().find("b.yaml:"), std::string::npos) << bad;
    }
  }
}

}  // namespace
}  // namespace lftrack::session
