// `lftrack register --sim` on every shipped real-CT scene, as a physicist first tries one (issue
// 51): the scene file as it ships, its light fields (the test cache's, where RealCtLoop builds them
// under content-keyed names), simulated frames at gold poses across the pose envelope, a cold
// registration from the nominal pose. Every result must be ACCEPTED by the verdict the loop's gate
// shares, and land on the gold pose. The thoracic clinical scene set up 8 mm superior failed this
// until the robust plan found the shift before the rotations (a 5.6-degree x rotation took it up).

#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

namespace fs = std::filesystem;
using test::lftrack_bin;

struct ShippedScene {
  const char* file;
  bool thoracic;
  // The largest mean TRE over the target box (mm) a registration may end at. When written, at 9
  // poses across the envelope: ideal scenes 0.004-0.14 mm; the clinical presets 0.19-0.46 mm
  // (BENCHMARKS.md, "Follow the target": `register --sim` across the envelope).
  double max_mean_tre_mm;
  const char* plan;  // the scene's tracking.plan, which a cold registration runs
  const char* other_patient;  // the shipped scene of the other CT, on the same preset
  const char* level_mm;       // one vertebral level of this spine
};

void PrintTo(const ShippedScene& s, std::ostream* os) { *os << s.file; }

class RegisterShippedScene : public ::testing::TestWithParam<ShippedScene> {};

TEST_P(RegisterShippedScene, SimulatedFramesAreAcceptedAtGoldPosesAcrossTheEnvelope) {
  const ShippedScene s = GetParam();
  LFTRACK_REQUIRE_SHARED_DATA(s.thoracic ? test::totalseg_aorta() : test::pancreas_dicom());
  const fs::path scene = fs::path(LFTRACK_SOURCE_DIR) / "scenes" / s.file;
  const fs::path fields = test::test_cache_dir() / "real-ct-light-fields";
  // tx,ty,tz mm, rx,ry,rz degrees from the nominal pose; the shipped envelope is 10 mm / 5 deg.
  for (const char* gold : {"0,0,8,0,0,0", "5,-5,5,2.5,-2.5,2.5", "-6,4,-3,-2,3,-1", "0,-8,0,0,0,4"}) {
    SCOPED_TRACE(std::string(s.file) + " at " + gold);
    std::string out;
    const Status run = run_process({lftrack_bin(), "-q", "register", "--scene", scene.string(), "--lf-dir",
                                    fields.string(), "--sim", "--gold", gold, "--seed", "1", "--json"},
                                   &out);
    EXPECT_TRUE(run.ok()) << "a rejected registration exits 1: " << out;
    const auto brace = out.find('{');
    ASSERT_NE(brace, std::string::npos) << out;
    const auto j = nlohmann::json::parse(out.substr(brace, out.rfind('}') - brace + 1));
    EXPECT_TRUE(j["verdict"]["ok"].get<bool>()) << j["verdict"].dump();
    EXPECT_EQ(j["plan"], s.plan);
    EXPECT_NE(j["stop"], "no finite cost") << j["stop"];
    EXPECT_LT(j["tre_mm"]["mean"].get<double>(), s.max_mean_tre_mm) << j["tre_mm"].dump();
    for (const auto& view : j["views"]) EXPECT_EQ(view["image_quality"], "ok") << view.dump();
  }
}

// The verdict as the scene ships it (its commissioning file, issue 52) on cases it was not
// commissioned from (another seed): one or two of every kind it must refuse (views swapped,
// frames mirrored, the patient beyond the envelope or one vertebral level off, the other CT's
// patient, noise, blank frames), and alignments and tracking registrations it must accept.
// `commission --check` fails on any false accept (and here on more than half the right results
// refused: one of four, on a CPU whose kernels round differently, is not what this asserts).
TEST_P(RegisterShippedScene, TheCommissionedVerdictRefusesEveryKindOfWrongFrame) {
  const ShippedScene s = GetParam();
  LFTRACK_REQUIRE_SHARED_DATA(test::totalseg_aorta());
  LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
  const fs::path scenes = fs::path(LFTRACK_SOURCE_DIR) / "scenes";
  const fs::path fields = test::test_cache_dir() / "real-ct-light-fields";
  test::TempDir report;
  std::string out;
  const Status run = run_process({lftrack_bin(), "-q", "commission", "--check", "--scene", (scenes / s.file).string(),
                                  "--other-scene", (scenes / s.other_patient).string(), "--level-mm", s.level_mm,
                                  "--lf-dir", fields.string(), "--good", "4", "--bad", "12", "--seed", "7",
                                  "--report", report.path().string(), "--max-false-rejects", "0.5"},
                                 &out);
  EXPECT_TRUE(run.ok()) << out;
  EXPECT_NE(out.find("scenes/commissioning/"), std::string::npos) << "the scene ships commissioned: " << out;
  for (const char* kind : {"swapped views", "mirrored", "beyond the envelope", "wrong level", "another patient",
                           "noise", "blank"})
    EXPECT_NE(out.find(std::string("  ") + kind + " "), std::string::npos) << kind << ": " << out;
}

INSTANTIATE_TEST_SUITE_P(
    ShippedScenes, RegisterShippedScene,
    ::testing::Values(ShippedScene{"lumbar-ct.yaml", false, 0.2, "quadratic", "thoracic-ct.yaml", "35"},
                      ShippedScene{"lumbar-ct-clinical.yaml", false, 0.8, "robust", "thoracic-ct-clinical.yaml", "35"},
                      ShippedScene{"thoracic-ct.yaml", true, 0.2, "quadratic", "lumbar-ct.yaml", "25"},
                      ShippedScene{"thoracic-ct-clinical.yaml", true, 0.8, "robust", "lumbar-ct-clinical.yaml", "25"}),
                         [](const ::testing::TestParamInfo<ShippedScene>& p) { return test::scene_test_name(p.param.file); });

}  // namespace
}  // namespace lftrack::session
