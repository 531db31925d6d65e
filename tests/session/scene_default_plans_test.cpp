// The plans a scene runs when it names none (issue 57): the robust plans for every frame that is
// not an ideal simulated DRR, the quadratic MI plans only for ideal simulated frames, and a named
// plan always kept.
#include <gtest/gtest.h>

#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_default_plans.hpp"

namespace lftrack::session {
namespace {

// `frames` is each detector's frames setting, a '#' in it standing for the detector's number (two
// detectors never share a device).
std::string scene_text(const std::string& frames, const std::string& extra) {
  return R"(version: 1
ct:
  path: ct_folder
roi:
  centre_mm: [0, 0, 0]
detectors:
)" + [&] {
    std::string list;
    for (const char* name : {"A", "B"}) {
      std::string own = frames;
      if (const auto hash = own.find('#'); hash != std::string::npos) own[hash] = name[0] == 'A' ? '1' : '2';
      list += std::string("  - name: ") + name + "\n    frames: " + own +
              "\n    rows: 64\n    cols: 64\n    pitch_mm: 0.4\n    isocentric:\n"
              "      source_direction: [" +
              (name[0] == 'A' ? "0.70710678" : "-0.70710678") +
              ", -0.70710678, 0]\n      up: [0, 0, 1]\n      source_to_isocentre_mm: 1000\n"
              "      source_to_detector_mm: 1500\n";
    }
    return list;
  }() + extra;
}

Scene parsed(const std::string& frames, const std::string& extra = "") {
  auto scene = parse_scene(scene_text(frames, extra), "scene.yaml", "/scenes");
  EXPECT_TRUE(scene.ok()) << scene.status().message();
  return scene.ok() ? *scene : Scene{};
}

void expect_plans(const Scene& s, const std::string& plan, const std::string& align,
                  const std::string& track) {
  EXPECT_EQ(s.registration.plan, plan);
  EXPECT_EQ(s.loop.align_plan, align);
  EXPECT_EQ(s.loop.track_plan, track);
}

TEST(SceneDefaultPlans, IdealSimulatedFramesKeepTheQuadraticMiPlans) {
  const Scene s = parsed("sim");
  EXPECT_TRUE(frames_are_ideal(s));
  expect_plans(s, "papers", "quadratic", "warm");
  EXPECT_NE(s.defaulted_plans.because.find("ideal"), std::string::npos) << s.defaulted_plans.because;
}

TEST(SceneDefaultPlans, RealisticSimulatedFramesGetTheRobustPlans) {
  for (const std::string physics : {"clinical", "{preset: ideal, scatter: {}}"}) {
    SCOPED_TRACE(physics);
    const Scene s = parsed("sim", "sim:\n  physics: " + physics + "\n");
    EXPECT_FALSE(frames_are_ideal(s));
    expect_plans(s, "robust", "robust", "warm-robust");
    EXPECT_NE(s.defaulted_plans.because.find("sim.physics"), std::string::npos) << s.defaulted_plans.because;
  }
}

TEST(SceneDefaultPlans, FramesFromDevicesOrAnArchiveGetTheRobustPlans) {
  // A device's frames carry scatter and a spectrum whatever the simulator's settings say.
  for (const std::string frames : {"{type: gige, camera: 127.0.0.#}", "{type: v4l2, device: /dev/video#}",
                                   "{type: replay, sequence: archive}"}) {
    SCOPED_TRACE(frames);
    const Scene s = parsed(frames, "sim:\n  physics: ideal\n");
    EXPECT_FALSE(frames_are_ideal(s));
    expect_plans(s, "robust", "robust", "warm-robust");
    EXPECT_FALSE(s.defaulted_plans.because.empty());
  }
  EXPECT_NE(parsed("{type: gige, camera: 127.0.0.#}").defaulted_plans.because.find("gige"),
            std::string::npos);
  EXPECT_NE(parsed("{type: replay, sequence: archive}").defaulted_plans.because.find("archived"),
            std::string::npos);
}

TEST(SceneDefaultPlans, ANamedPlanIsKeptAndOnlyTheOthersAreChosen) {
  const Scene some = parsed("{type: gige, camera: 127.0.0.#}", "loop:\n  track_plan: warm\n");
  expect_plans(some, "robust", "robust", "warm");
  EXPECT_FALSE(some.defaulted_plans.because.empty());
  EXPECT_TRUE(some.defaulted_plans.plan && some.defaulted_plans.align && !some.defaulted_plans.track);
  // The log line says which plan the scene named and which was chosen, and why.
  EXPECT_EQ(describe_loop_plans(some),
            "align robust (the default for frames from gige devices), track warm (the scene's)");

  const Scene all =
      parsed("{type: gige, camera: 127.0.0.#}",
             "tracking:\n  plan: quadratic\nloop:\n  align_plan: pyramid\n  track_plan: warm\n");
  expect_plans(all, "quadratic", "pyramid", "warm");
  EXPECT_TRUE(all.defaulted_plans.because.empty()) << all.defaulted_plans.because;

  const Scene ideal = parsed("sim", "tracking:\n  plan: robust\n");
  expect_plans(ideal, "robust", "quadratic", "warm");
}

TEST(SceneDefaultPlans, AReplayedArchiveTakesTheRobustPlansForThePlansLeftOpen) {
  Scene s = parsed("sim", "loop:\n  track_plan: warm\n");
  expect_plans(s, "papers", "quadratic", "warm");
  apply_default_plans(archived_frame_plans(), &s);
  expect_plans(s, "robust", "robust", "warm");
  EXPECT_NE(s.defaulted_plans.because.find("archived"), std::string::npos);
}

TEST(SceneDefaultPlans, EveryDefaultIsAPlanTheRegistrationKnows) {
  for (const std::string frames : {"sim", "{type: gige, camera: 127.0.0.#}"}) {
    const Scene s = parsed(frames);
    const auto d = default_plans(s);
    for (const auto& name : {d.plan, d.align_plan, d.track_plan}) {
      SCOPED_TRACE(name);
      const std::string text =
          scene_text(frames, "tracking:\n  plan: " + name + "\nloop:\n  align_plan: " + name + "\n");
      EXPECT_TRUE(parse_scene(text, "scene.yaml", "/scenes").ok());
    }
  }
}

}  // namespace
}  // namespace lftrack::session
