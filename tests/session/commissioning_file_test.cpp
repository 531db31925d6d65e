// A scene's commissioning file (commissioning_file.hpp) and the verdict limits taken from it
// (scene_verdict_limits): read back as written, never replaced unasked, refused with its name when
// malformed, and refused for a scene whose CT, room, registration or imaging it was not measured on.

#include "lftrack/session/commissioning_file.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <memory>
#include <sstream>

#include "lftrack/session/scene_verdict.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;

class CommissioningFile : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tracking::ThreadPool pool(2);
    auto scene = load_scene("builtin:phantom");
    ASSERT_TRUE(scene.ok());
    auto p = prepare_scene(*scene, "", &pool);
    ASSERT_TRUE(p.ok()) << p.status().message();
    phantom_ = std::make_unique<PreparedScene>(std::move(p).value());
  }
  static void TearDownTestSuite() { phantom_.reset(); }

  static CommissioningRecord record_of(const PreparedScene& p) {
    CommissioningRecord r;
    r.fingerprint = commissioning_fingerprint(p);
    r.measure = p.scene.registration.similarity;
    r.min_similarity = 0.9;
    r.min_check_ncc = 0.85;
    r.scene = "builtin:phantom";
    r.made_utc = "2026-11-30T12:00:00Z";
    r.command = "lftrack commission --scene \"builtin:phantom\" --out c.yaml";
    return r;
  }
  static std::string read(const fs::path& file) {
    std::ifstream in(file);
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
  }

  static std::unique_ptr<PreparedScene> phantom_;
  test::TempDir dir_;
};
std::unique_ptr<PreparedScene> CommissioningFile::phantom_;

TEST_F(CommissioningFile, ReadsBackWhatItWroteAndFitsItsScene) {
  const fs::path file = dir_.path() / "c.yaml";
  const CommissioningRecord written = record_of(*phantom_);
  ASSERT_TRUE(write_commissioning_file(file, written, "measured:\n  cases: 3\n", false).ok());
  auto read_back = read_commissioning_file(file);
  ASSERT_TRUE(read_back.ok()) << read_back.status().message();
  EXPECT_EQ(read_back->fingerprint, written.fingerprint);
  EXPECT_EQ(read_back->measure, written.measure);
  EXPECT_DOUBLE_EQ(read_back->min_similarity, 0.9);
  EXPECT_DOUBLE_EQ(read_back->min_check_ncc, 0.85);
  EXPECT_EQ(read_back->command, written.command);  // quotes inside survive
  EXPECT_TRUE(check_commissioning_current(*phantom_, *read_back, file).ok());
  EXPECT_NE(read(file).find("cases: 3"), std::string::npos);
}

TEST_F(CommissioningFile, AnotherRoomOrMeasureIsRefusedNamingWhatDiffers) {
  const fs::path file = dir_.path() / "c.yaml";
  const CommissioningRecord r = record_of(*phantom_);
  PreparedScene wider = *phantom_;
  wider.scene.envelope.translation_mm = 20;
  Status s = check_commissioning_current(wider, r, file);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("the room"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("lftrack commission --scene"), std::string::npos) << s.message();
  EXPECT_EQ(s.message().find("the CT"), std::string::npos) << s.message();

  PreparedScene other_measure = *phantom_;
  other_measure.scene.registration.similarity = "ncc";
  s = check_commissioning_current(other_measure, r, file);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("the registration"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("the measure (mi commissioned, ncc now)"), std::string::npos) << s.message();

  PreparedScene other_dose = *phantom_;
  other_dose.scene.sim.photons_per_pixel *= 2;
  s = check_commissioning_current(other_dose, r, file);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("the imaging"), std::string::npos) << s.message();

  PreparedScene other_ct = *phantom_;
  auto mu = std::make_shared<tracking::MuVolume>(*phantom_->mu);
  mu->values[mu->values.size() / 2] += 0.001f;  // one voxel
  other_ct.mu = mu;
  s = check_commissioning_current(other_ct, r, file);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("the CT"), std::string::npos) << s.message();
}

TEST_F(CommissioningFile, AnExistingFileIsReplacedOnlyWhenAsked) {
  const fs::path file = dir_.path() / "c.yaml";
  CommissioningRecord r = record_of(*phantom_);
  ASSERT_TRUE(write_commissioning_file(file, r, "", false).ok());
  const std::string first = read(file);
  r.min_similarity = 1.1;
  const Status refused = write_commissioning_file(file, r, "", false);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.message().find("--replace"), std::string::npos) << refused.message();
  EXPECT_EQ(read(file), first);
  ASSERT_TRUE(write_commissioning_file(file, r, "", true).ok());
  EXPECT_DOUBLE_EQ(read_commissioning_file(file)->min_similarity, 1.1);
  for (const auto& entry : fs::directory_iterator(dir_.path()))
    EXPECT_EQ(entry.path().filename().string().find(".partial"), std::string::npos) << entry.path();
}

TEST_F(CommissioningFile, MalformedFilesAreRefusedWithTheirName) {
  const fs::path good = dir_.path() / "good.yaml";
  ASSERT_TRUE(write_commissioning_file(good, record_of(*phantom_), "", false).ok());
  const std::string text = read(good);
  const auto variant = [&](const std::string& from, const std::string& to) {
    std::string changed = text;
    const auto at = changed.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    if (at != std::string::npos) changed.replace(at, from.size(), to);
    return changed;
  };
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"not yaml", "floors: [1, 2\n"},
      {"a list", "- 1\n- 2\n"},
      {"another tool's", "name: something\n"},
      {"no floors", variant("floors:", "flooring:")},
      {"check NCC 1.5", variant("min_check_ncc: 0.85", "min_check_ncc: 1.5")},
      {"NaN floor", variant("min_similarity: 0.9", "min_similarity: .nan")},
      {"text floor", variant("min_similarity: 0.9", "min_similarity: high")},
      {"no CT fingerprint", variant("  ct: ", "  cat: ")},
      {"version 2", variant("lftrack_commissioning: 1", "lftrack_commissioning: 2")},
      {"a floor edited by hand", variant("min_similarity: 0.9 ", "min_similarity: 0.5 ")},
      {"no seal", variant("seal: ", "sealed: ")},
      {"the record edited", variant("scene: \"builtin:phantom\"", "scene: \"another\"")},
      {"a key added", variant("measure: mi\n", "measure: mi\nextra: 1\n")},
      {"a floor given twice", variant("  min_check_ncc: 0.85", "  min_check_ncc: 0.85\n  min_check_ncc: 0.40")},
      {"empty", ""},
  };
  for (const auto& [what, content] : bad) {
    SCOPED_TRACE(what);
    const fs::path file = dir_.path() / "bad.yaml";
    std::ofstream(file, std::ios::trunc) << content;
    auto r = read_commissioning_file(file);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find(file.string()), std::string::npos) << r.status().message();
  }
  auto missing = read_commissioning_file(dir_.path() / "none.yaml");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
}

// Floors below what commissioning chooses would switch a check off: refused even when sealed.
TEST_F(CommissioningFile, AFloorThatSwitchesACheckOffIsRefused) {
  for (const auto& [similarity, check] : {std::pair{-1e9, 0.85}, std::pair{0.9, 0.01}, std::pair{0.1, 0.85}}) {
    CommissioningRecord r = record_of(*phantom_);
    r.min_similarity = similarity;  // mi: at least 0.15 (halfway from 0 to the default 0.3)
    r.min_check_ncc = check;        // at least 0.38
    const fs::path file = dir_.path() / "low.yaml";
    ASSERT_TRUE(write_commissioning_file(file, r, "", true).ok());
    auto read_back = read_commissioning_file(file);
    ASSERT_FALSE(read_back.ok()) << similarity << " " << check;
    EXPECT_NE(read_back.status().message().find("floors below"), std::string::npos) << read_back.status().message();
  }
}

TEST_F(CommissioningFile, TheVerdictTakesItsFloorsFromTheFileTheSceneNames) {
  const fs::path file = dir_.path() / "c.yaml";
  ASSERT_TRUE(write_commissioning_file(file, record_of(*phantom_), "", false).ok());
  PreparedScene p = *phantom_;
  std::string from;
  auto defaults = scene_verdict_limits(p, "mi", &from);
  ASSERT_TRUE(defaults.ok());
  EXPECT_NE(from.find("not commissioned"), std::string::npos) << from;

  p.scene.commissioning_file = file.string();
  auto limits = scene_verdict_limits(p, "mi", &from);
  ASSERT_TRUE(limits.ok()) << limits.status().message();
  EXPECT_DOUBLE_EQ(limits->min_similarity, 0.9);
  EXPECT_DOUBLE_EQ(limits->min_check_ncc, 0.85);
  EXPECT_EQ(from, file.string());
  // Another measure (register --similarity ncc): the measure at its default floor, the check at
  // the higher of the file's and the default (the file's floors were chosen together).
  auto ncc = scene_verdict_limits(p, "ncc", &from);
  ASSERT_TRUE(ncc.ok());
  EXPECT_DOUBLE_EQ(ncc->min_similarity, 0.76);
  EXPECT_DOUBLE_EQ(ncc->min_check_ncc, 0.85);
  CommissioningRecord low_check = record_of(*phantom_);
  low_check.min_check_ncc = 0.5;
  ASSERT_TRUE(write_commissioning_file(file, low_check, "", true).ok());
  EXPECT_DOUBLE_EQ(scene_verdict_limits(p, "ncc")->min_check_ncc, 0.76);
  EXPECT_DOUBLE_EQ(scene_verdict_limits(p, "mi")->min_check_ncc, 0.5);

  p.scene.commissioning_file = (dir_.path() / "none.yaml").string();
  auto missing = scene_verdict_limits(p, "mi");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("lftrack commission --scene"), std::string::npos)
      << missing.status().message();

  p.scene.commissioning_file = file.string();
  p.scene.envelope.rotation_deg = 3;
  EXPECT_FALSE(scene_verdict_limits(p, "mi").ok());
}

// The view check's commissioned limit: read back, taken by the verdict, never above the scene's
// own safety.max_view_shift_mm, out-of-range values refused, and a scene whose own limit changed
// is refused as another registration (the fingerprint holds it).
TEST_F(CommissioningFile, TheViewChecksLimitIsTheFilesWithinTheScenes) {
  const fs::path file = dir_.path() / "v.yaml";
  CommissioningRecord r = record_of(*phantom_);
  r.max_view_shift_mm = 0.35;
  ASSERT_TRUE(write_commissioning_file(file, r, "", false).ok());
  EXPECT_NE(read(file).find("max_view_shift_mm: 0.35"), std::string::npos) << read(file);
  auto read_back = read_commissioning_file(file);
  ASSERT_TRUE(read_back.ok()) << read_back.status().message();
  EXPECT_DOUBLE_EQ(read_back->max_view_shift_mm, 0.35);
  PreparedScene p = *phantom_;
  p.scene.commissioning_file = file.string();
  auto limits = scene_verdict_limits(p, "mi");
  ASSERT_TRUE(limits.ok()) << limits.status().message();
  EXPECT_DOUBLE_EQ(limits->max_view_shift_mm, 0.35);
  // Written without one (a scene with no view check): the scene's own limit stands.
  r.max_view_shift_mm = 0;
  ASSERT_TRUE(write_commissioning_file(file, r, "", true).ok());
  EXPECT_EQ(read(file).find("max_view_shift_mm"), std::string::npos);
  EXPECT_DOUBLE_EQ(scene_verdict_limits(p, "mi")->max_view_shift_mm, 1.0);
  for (double bad : {-0.1, 25.0}) {
    r.max_view_shift_mm = bad;
    ASSERT_TRUE(write_commissioning_file(file, r, "", true).ok());
    auto refused = read_commissioning_file(file);
    ASSERT_FALSE(refused.ok()) << bad;
    EXPECT_NE(refused.status().message().find("max_view_shift_mm out of range"), std::string::npos)
        << refused.status().message();
  }
  PreparedScene wider = *phantom_;
  wider.scene.verdict_checks.max_view_shift_mm = 2;
  EXPECT_NE(commissioning_fingerprint(wider).registration, commissioning_fingerprint(*phantom_).registration);
  PreparedScene edge = *phantom_;
  edge.scene.verdict_checks.envelope_edge_mm = 1;
  EXPECT_NE(commissioning_fingerprint(edge).registration, commissioning_fingerprint(*phantom_).registration);
}

TEST_F(CommissioningFile, TheSceneNamesItBesideItselfAndNotWithAFloorOfItsOwn) {
  std::string text = *builtin_scene_text("builtin:phantom");
  const std::string safety = "safety:\n";
  std::string named = text;
  named.replace(named.find(safety), safety.size(), "safety:\n  commissioning: phantom.commissioning.yaml\n");
  auto scene = parse_scene(named, "s.yaml", dir_.path());
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->commissioning_file, (dir_.path() / "phantom.commissioning.yaml").string());

  std::string both = text;
  both.replace(both.find(safety), safety.size(), "safety:\n  commissioning: c.yaml\n  min_similarity: 0.5\n");
  auto refused = parse_scene(both, "s.yaml", dir_.path());
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("safety.commissioning"), std::string::npos) << refused.status().message();

  std::string empty = text;
  empty.replace(empty.find(safety), safety.size(), "safety:\n  commissioning: ''\n");
  EXPECT_FALSE(parse_scene(empty, "s.yaml", dir_.path()).ok());
}

}  // namespace
}  // namespace lftrack::session
