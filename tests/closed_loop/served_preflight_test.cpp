// `lftrack run`'s start-up checks (preflight.hpp) against the served GigE twins: `lftrack serve
// detectors` serves each of the scene's detectors as a fake GigE Vision camera that names itself
// after the detector. Each detector must answer as itself: two camera addresses swapped in the
// scene fail the check, naming which detector answered where (issue 50: they passed, and the run
// then failed its alignment for a reason that did not point at the cabling).

#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <optional>
#include <string>

#include "child_process.hpp"
#include "gige_host_lock.hpp"
#include "lftrack/session/preflight.hpp"
#include "lftrack/sim/gige_fake_detector.hpp"
#include "loop_fixture.hpp"

namespace lftrack::session {

using loop::RealtimeReport;
namespace {

using namespace std::chrono_literals;

class ServedPreflight : public ClosedLoop {
 protected:
  // The start-up checks of the fixture's scene with GigE detectors at `addresses` (in the
  // scene's order), `calibration: simulator`, and no actuator.
  PreflightReport check(const std::vector<std::string>& addresses) {
    Scene scene = small_scene(kBreathing, kLightFieldFrames);
    scene.actuator.type = "none";
    for (std::size_t i = 0; i < scene.detectors.size(); ++i) {
      scene.detectors[i].frames.kind = "gige";
      scene.detectors[i].frames.device = addresses[i];
      scene.detectors[i].simulator_calibration = true;
    }
    if (edit_scene_) edit_scene_(scene);
    auto prepared = prepare_scene(scene, "", pool_);
    EXPECT_TRUE(prepared.ok()) << prepared.status().message();
    if (!prepared.ok()) return {};
    LoopSessionOptions options;
    options.light_field_dir = shared_light_field_dir(*prepared);
    return run_preflight(*prepared, options, RealtimeReport{}, true);
  }

  static const PreflightItem* item(const PreflightReport& r, const std::string& starts) {
    for (const PreflightItem& i : r.items)
      if (i.what.rfind(starts, 0) == 0) return &i;
    return nullptr;
  }
};

TEST_F(ServedPreflight, EachDetectorMustAnswerAsItselfSoSwappedAddressesFail) {
  const std::vector<std::string> addresses = sim::local_ipv4_addresses();
  if (addresses.size() < 2)
    GTEST_SKIP() << "one GigE camera per detector needs two local IPv4 addresses; this host has " << addresses.size();
  test::GigeHostLock gige_tests_one_at_a_time;
  const std::filesystem::path dir = dir_.path();
  std::ofstream(dir / "room.yaml") << small_scene_text(kBreathing, kLightFieldFrames);
  test::ChildProcess detectors({LFTRACK_BIN_PATH, "-q", "serve", "detectors", "--scene", (dir / "room.yaml").string(),
                                "--address", addresses[0], "--address", addresses[1], "--lf-dir",
                                small_scene_light_field_dir().string(), "--threads", "1"});
  const std::optional<std::string> listening = detectors.read_line(120s);
  ASSERT_TRUE(listening.has_value()) << "the detector server started";
  if (listening->find("gige") == std::string::npos) GTEST_SKIP() << *listening;

  const PreflightReport right = check({addresses[0], addresses[1]});
  const PreflightItem* found = item(right, "detectors A B");
  ASSERT_NE(found, nullptr) << right.checklist();
  EXPECT_EQ(found->result, CheckResult::kPass) << right.checklist();
  for (const std::string& said : std::vector<std::string>{"A at " + addresses[0], "LFTRACK-A", "B at " + addresses[1], "LFTRACK-B"})
    EXPECT_NE(found->detail.find(said), std::string::npos) << "says who answered where (" << said << "): " << found->detail;
  // The served twins are the simulator's: its detector model is theirs (a warning, not a failure).
  for (const char* calibration : {"detector calibration of A", "detector calibration of B"}) {
    const PreflightItem* c = item(right, calibration);
    ASSERT_NE(c, nullptr) << right.checklist();
    EXPECT_EQ(c->result, CheckResult::kWarn) << c->detail;
  }

  const PreflightReport swapped = check({addresses[1], addresses[0]});
  found = item(swapped, "detectors A B");
  ASSERT_NE(found, nullptr) << swapped.checklist();
  EXPECT_EQ(found->result, CheckResult::kFail) << swapped.checklist();
  for (const std::string& said : std::vector<std::string>{"A at " + addresses[1], "LFTRACK-B", "B at " + addresses[0], "LFTRACK-A"})
    EXPECT_NE(found->detail.find(said), std::string::npos) << "names both ids (" << said << "): " << found->detail;
  EXPECT_FALSE(swapped.passed());
}

}  // namespace
}  // namespace lftrack::session
