// `lftrack commission` as a physicist runs it (issue 52): it measures the verdict's floors for a
// scene from known-good and known-bad cases and writes the scene's commissioning file, which it
// never overwrites unasked; `register` then judges with those floors, refuses the scene once its
// room differs from what was commissioned, and `commission --check` judges new cases with them.

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/session/commissioning_file.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

namespace fs = std::filesystem;

// The built-in phantom with a coarse light field (built once in a few seconds), naming its
// commissioning file; and the same scene with a wider envelope naming the same file.
class CommissionCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = std::make_unique<test::TempDir>();
    std::string scene = test::coarse_phantom_scene_text();
    const std::string safety = "safety:\n";
    scene.replace(scene.find(safety), safety.size(), "safety:\n  commissioning: phantom.commissioning.yaml\n");
    std::ofstream(dir_->path() / "phantom.yaml") << scene;
    const std::string envelope = "  translation_mm: 10\n";
    scene.replace(scene.find(envelope), envelope.size(), "  translation_mm: 12\n");
    std::ofstream(dir_->path() / "wider.yaml") << scene;
  }
  static void TearDownTestSuite() { dir_.reset(); }

  static Status lftrack(std::vector<std::string> args, std::string* out) {
    std::vector<std::string> argv = {LFTRACK_BIN_PATH, "-q"};
    argv.insert(argv.end(), args.begin(), args.end());
    return run_process(argv, out);
  }
  static fs::path dir() { return dir_->path(); }
  // The fingerprint of the suite's scene, prepared here as the program prepares it.
  static CommissioningFingerprint commissioning_fingerprint_of_test_scene() {
    auto scene = load_scene((dir() / "phantom.yaml").string());
    EXPECT_TRUE(scene.ok()) << scene.status().message();
    tracking::ThreadPool pool(2);
    auto prepared = prepare_scene(*scene, "", &pool);
    EXPECT_TRUE(prepared.ok()) << prepared.status().message();
    return prepared.ok() ? commissioning_fingerprint(*prepared) : CommissioningFingerprint{};
  }
  static std::vector<std::string> commission(const std::string& scene, std::vector<std::string> more,
                                             const std::string& good = "10", const std::string& bad = "70") {
    std::vector<std::string> args = {"commission", "--scene", (dir() / scene).string(), "--lf-dir",
                                     (dir() / "lf").string(), "--good", good, "--bad", bad,
                                     "--report", (dir() / "report").string(),
                                     // What is asserted is what the verdict accepts; one right result
                                     // refused of four (a CPU's kernels) is not this test's concern.
                                     "--max-false-rejects", "0.5"};
    args.insert(args.end(), more.begin(), more.end());
    return args;
  }

  static std::unique_ptr<test::TempDir> dir_;
};
std::unique_ptr<test::TempDir> CommissionCli::dir_;

TEST_F(CommissionCli, CommissionsTheSceneAndRegisterJudgesWithItsFloors) {
  const fs::path file = dir() / "phantom.commissioning.yaml";
  std::string out;
  // Before it is commissioned, a scene that names the file is refused, saying how to make it.
  ASSERT_FALSE(lftrack({"register", "--scene", (dir() / "phantom.yaml").string(), "--lf-dir", (dir() / "lf").string(),
                        "--sim"},
                       &out)
                   .ok());
  EXPECT_NE(out.find("lftrack commission --scene"), std::string::npos) << out;

  ASSERT_TRUE(lftrack(commission("phantom.yaml", {}), &out).ok()) << out;
  EXPECT_NE(out.find("at the measure's default floors"), std::string::npos) << out;
  EXPECT_NE(out.find("held out"), std::string::npos) << out;
  auto record = read_commissioning_file(file);
  ASSERT_TRUE(record.ok()) << record.status().message();
  EXPECT_EQ(record->measure, "mi");
  EXPECT_EQ(record->fingerprint, commissioning_fingerprint_of_test_scene()) << "made for the scene it names";
  EXPECT_NE(out.find("false accepts 0.00 %"), std::string::npos) << out;
  // Every case in the report: a header and 80 rows (10 good, 70 bad).
  const std::string csv = test::contents(dir() / "report" / "cases.csv");
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 81) << csv;
  for (const char* kind : {"align", "track", "swapped views", "mirrored", "beyond the envelope", "wrong level", "noise",
                           "blank"})
    EXPECT_NE(csv.find(std::string("\n") + kind + ","), std::string::npos) << kind;

  // Not overwritten unasked: the second run refuses before it measures anything.
  const std::string first = test::contents(file);
  EXPECT_FALSE(lftrack(commission("phantom.yaml", {}), &out).ok());
  EXPECT_NE(out.find("--replace"), std::string::npos) << out;
  EXPECT_EQ(test::contents(file), first);

  // register judges with the file's floors.
  ASSERT_TRUE(lftrack({"register", "--scene", (dir() / "phantom.yaml").string(), "--lf-dir", (dir() / "lf").string(),
                       "--sim", "--gold", "2,-1,1.5,1,0.5,-1", "--json"},
                      &out)
                  .ok())
      << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{'), out.rfind('}') - out.find('{') + 1));
  EXPECT_TRUE(j["verdict"]["ok"].get<bool>()) << j.dump();
  EXPECT_EQ(fs::path(j["verdict"]["floors_from"].get<std::string>()), file) << j.dump();

  // The same file for a scene with another envelope: refused, naming what differs.
  EXPECT_FALSE(lftrack({"register", "--scene", (dir() / "wider.yaml").string(), "--lf-dir", (dir() / "lf").string(),
                        "--sim"},
                       &out)
                   .ok());
  EXPECT_NE(out.find("commissioned for another scene"), std::string::npos) << out;
  EXPECT_NE(out.find("the room"), std::string::npos) << out;

  // New cases (another seed) judged by the commissioned verdict: nothing wrong accepted.
  ASSERT_TRUE(lftrack(commission("phantom.yaml", {"--check", "--seed", "5"}, "4", "14"), &out).ok()) << out;
  EXPECT_NE(out.find("at the scene's floors"), std::string::npos) << out;
  EXPECT_EQ(test::contents(file), first);  // --check writes nothing
}

// (Out-of-range options are Cli/UsageError cases.)
TEST_F(CommissionCli, NoCasesOrACheckThatWouldWriteIsRefused) {
  std::string out;
  // No cases at all, and --check with --replace: refused with a reason, nothing run.
  EXPECT_FALSE(lftrack(commission("phantom.yaml", {"--dry-run"}, "0", "0"), &out).ok());
  EXPECT_NE(out.find("no cases"), std::string::npos) << out;
  EXPECT_FALSE(lftrack(commission("phantom.yaml", {"--check", "--replace"}), &out).ok());
  EXPECT_NE(out.find("excludes"), std::string::npos) << out;
  // Too few cases to write a file from.
  EXPECT_FALSE(lftrack(commission("phantom.yaml", {"--out", (dir() / "few.yaml").string()}, "4", "10"), &out).ok());
  EXPECT_NE(out.find("at least 10 good and 70 bad"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(dir() / "few.yaml"));
}

// --replace replaces a commissioning file and nothing else: not the scene, not another file, not
// a link; and the commissioning file never goes into the report folder.
TEST_F(CommissionCli, ReplaceReplacesOnlyACommissioningFile) {
  std::string out;
  const fs::path scene = dir() / "phantom.yaml";
  const std::string scene_text = test::contents(scene);
  const fs::path notes = dir() / "notes.txt";
  std::ofstream(notes) << "my notes\n";
  fs::create_symlink(notes, dir() / "link.yaml");
  for (const fs::path& target : {scene, notes, dir() / "link.yaml", dir() / "report" / "c.yaml"}) {
    SCOPED_TRACE(target.string());
    EXPECT_FALSE(lftrack(commission("phantom.yaml", {"--out", target.string(), "--replace"}), &out).ok());
    EXPECT_EQ(out.find(" cases in "), std::string::npos) << "refused before any case ran: " << out;
  }
  EXPECT_EQ(test::contents(scene), scene_text);
  EXPECT_EQ(test::contents(notes), "my notes\n");
  EXPECT_TRUE(fs::is_symlink(dir() / "link.yaml"));
}

}  // namespace
}  // namespace lftrack::session
