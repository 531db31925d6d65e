// A scene's light-field files (scene.hpp, "Light-field files"): named after what each field
// depends on, so scenes sharing a folder keep their own fields and nothing up to date is built
// again (issue 50: a run of another scene with the same --lf-dir replaced a patient's fields).

#include <gtest/gtest.h>

#include <fstream>
#include <iterator>
#include <map>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;

std::string bytes_of(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

class LightFieldCache : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    pool_ = new tracking::ThreadPool(2);
    auto scene = load_scene("builtin:phantom");
    ASSERT_TRUE(scene.ok());
    scene->light_field.resolution = {4, 4, 48, 48};  // built in a moment
    auto prepared = prepare_scene(*scene, "", pool_);
    ASSERT_TRUE(prepared.ok()) << prepared.status().message();
    phantom_ = new PreparedScene(std::move(prepared).value());
  }
  static void TearDownTestSuite() {
    delete phantom_;
    delete pool_;
  }
  // Every file of `dir` with its bytes.
  static std::map<std::string, std::string> folder(const fs::path& dir) {
    std::map<std::string, std::string> files;
    for (const auto& e : fs::directory_iterator(dir)) files[e.path().filename().string()] = bytes_of(e.path());
    return files;
  }
  Result<std::vector<std::shared_ptr<const tracking::LightField>>> cached(const PreparedScene& p, const fs::path& dir,
                                                                          LightFieldCacheReport* report) {
    return load_or_build_light_fields(p, *p.mu, p.scene.light_field, dir, pool_, report);
  }
  static inline tracking::ThreadPool* pool_ = nullptr;
  static inline PreparedScene* phantom_ = nullptr;
};

TEST_F(LightFieldCache, ScenesSharingAFolderKeepTheirFieldsAndNothingUpToDateIsBuiltAgain) {
  test::TempDir dir;
  const fs::path lf = dir.path() / "lf";
  const PreparedScene& first = *phantom_;
  PreparedScene wider = first;  // the same patient, another envelope: another geometry
  wider.scene.envelope.rotation_deg += 1;
  PreparedScene other_ct = first;  // another patient: one voxel differs
  auto mu = std::make_shared<tracking::MuVolume>(*first.mu);
  mu->values[mu->values.size() / 2] += 0.01f;
  other_ct.mu = mu;

  LightFieldCacheReport report;
  ASSERT_TRUE(cached(first, lf, &report).ok());
  EXPECT_EQ(report.built, (std::vector<bool>{true, true}));
  const std::vector<fs::path> first_files = report.files;
  const auto after_first = folder(lf);
  ASSERT_EQ(after_first.size(), 2u);
  for (const fs::path& f : first_files) EXPECT_EQ(f.parent_path(), lf);

  for (const PreparedScene* p : {&wider, &other_ct}) {
    ASSERT_TRUE(cached(*p, lf, &report).ok());
    EXPECT_EQ(report.built, (std::vector<bool>{true, true}));
    for (std::size_t i = 0; i < 2; ++i) EXPECT_NE(report.files[i], first_files[i]);
  }
  const auto after_all = folder(lf);
  EXPECT_EQ(after_all.size(), 6u);
  for (const auto& [name, bytes] : after_first) EXPECT_EQ(after_all.at(name), bytes) << name << " was replaced";

  // Each again: loaded, nothing built, nothing written.
  for (const PreparedScene* p : std::initializer_list<const PreparedScene*>{&first, &wider, &other_ct}) {
    auto fields = cached(*p, lf, &report);
    ASSERT_TRUE(fields.ok()) << fields.status().message();
    EXPECT_EQ(report.built, (std::vector<bool>{false, false}));
    auto loaded = load_light_fields(*p, lf);
    ASSERT_TRUE(loaded.ok()) << loaded.status().message();
    EXPECT_EQ((*loaded)[0]->header().plan_hash, (*fields)[0]->header().plan_hash);
  }
  EXPECT_EQ(folder(lf), after_all);
}

// A field not there is refused naming every setting in which the newest field of its view in the
// folder differs, the integration and its slice step too.
TEST_F(LightFieldCache, AMissingFieldNamesEverySettingTheFieldThereDiffersIn) {
  test::TempDir dir;
  const fs::path lf = dir.path() / "lf";
  ASSERT_TRUE(cached(*phantom_, lf, nullptr).ok());
  PreparedScene sliced = *phantom_;
  sliced.scene.light_field.integration = tracking::LightFieldIntegration::kSlices;
  sliced.scene.light_field.slice_step_mm = 0.5;
  sliced.scene.envelope.translation_mm += 2;
  auto loaded = load_light_fields(sliced, lf);
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), StatusCode::kNotFound);
  const std::string why = loaded.status().message();
  for (const std::string& named :
       {std::string("no light field of view A for these settings"), std::string("was built with other settings: "),
        std::string("envelope translation_mm"), std::string("integration (siddon in the file, slices now)"),
        std::string("slice_step_mm (0 (the CT's finest spacing) in the file, 0.5 now)"),
        std::string("run `lftrack precompute`")})
    EXPECT_NE(why.find(named), std::string::npos) << named << " in: " << why;
  // Nothing there at all: what to run.
  auto none = load_light_fields(sliced, dir.path() / "none");
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.status().message().find("run `lftrack precompute`"), std::string::npos);
}

// A field under the name lftrack gave fields before (<view>.lf) is used where it is the field
// asked for; one that is not is left alone and the new field written beside it.
TEST_F(LightFieldCache, AFieldOfTheEarlierNameIsUsedWhenItIsTheFieldAskedFor) {
  test::TempDir dir;
  const fs::path built = dir.path() / "built", earlier = dir.path() / "earlier";
  LightFieldCacheReport report;
  ASSERT_TRUE(cached(*phantom_, built, &report).ok());
  fs::create_directories(earlier);
  for (std::size_t i = 0; i < 2; ++i)
    fs::copy_file(report.files[i], earlier / (phantom_->scene.detectors[i].view.name + ".lf"));
  ASSERT_TRUE(cached(*phantom_, earlier, &report).ok());
  EXPECT_EQ(report.built, (std::vector<bool>{false, false}));
  EXPECT_EQ(folder(earlier).size(), 2u);
  PreparedScene wider = *phantom_;
  wider.scene.envelope.rotation_deg += 1;
  const auto before = folder(earlier);
  ASSERT_TRUE(cached(wider, earlier, &report).ok());
  EXPECT_EQ(report.built, (std::vector<bool>{true, true}));
  const auto after = folder(earlier);
  EXPECT_EQ(after.size(), 4u);
  for (const auto& [name, bytes] : before) EXPECT_EQ(after.at(name), bytes) << name << " was replaced";
}

}  // namespace
}  // namespace lftrack::session
