// `lftrack sim` as a user runs it, on what issue 18 found: absurd --auto-resume values, records
// overwritten (journal, archive), a control socket over the journal, and offline runs that took
// real-time priority. Each run is a few cycles of a scene with tiny light fields.

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <iterator>
#include <string>

#include <nlohmann/json.hpp>

#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

namespace fs = std::filesystem;

class SimRecords : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    shared_ = new test::TempDir();
    std::string scene = *builtin_scene_text(kBuiltinPhantom);
    for (const std::string field :
         {"    resolution: [16, 16, 128, 128]\n", "    resolution: [24, 24, 192, 192]\n"})
      scene.replace(scene.find(field), field.size(), "    resolution: [6, 6, 48, 64]\n");
    std::ofstream(shared_->path() / "sim.yaml") << scene;
  }
  static void TearDownTestSuite() { delete shared_; }

  // `lftrack -q sim` on the small scene for `cycles` cycles, on the simulated clock, in `cwd`.
  Status sim(const std::vector<std::string>& args, std::string* out, int cycles = 3, const fs::path& cwd = {}) {
    std::vector<std::string> argv = {LFTRACK_BIN_PATH, "-q", "sim", "--scene", (shared_->path() / "sim.yaml").string(),
                                     "--fast", "--cycles", std::to_string(cycles), "--lf-dir",
                                     (shared_->path() / "lf").string()};
    argv.insert(argv.end(), args.begin(), args.end());
    if (cwd.empty()) return run_process(argv, out);
    std::string command = "cd '" + cwd.string() + "' && exec";
    for (const std::string& a : argv) command += " '" + a + "'";
    return run_process({"/bin/sh", "-c", command}, out);
  }

  static std::string contents(const fs::path& file) {
    std::ifstream in(file, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }

  static inline test::TempDir* shared_ = nullptr;
  test::TempDir dir_;
};

TEST_F(SimRecords, AutoResumeRefusesNanInfiniteNegativeAndHugeBeforeRunning) {
  for (const char* bad : {"inf", "nan", "-1", "1e12", "-inf", "3601", "soon"}) {
    std::string out;
    const Status s = sim({"--auto-resume", bad, "--journal", ""}, &out);
    EXPECT_FALSE(s.ok()) << bad << ": " << out;
    EXPECT_NE(out.find("--auto-resume"), std::string::npos) << bad << ": " << out;
    EXPECT_EQ(out.find("cycles"), std::string::npos) << bad << ": refused before the loop ran: " << out;
  }
  std::string out;
  EXPECT_TRUE(sim({"--auto-resume", "0.5", "--journal", ""}, &out).ok()) << out;
}

TEST_F(SimRecords, AJournalIsNeverOverwrittenUnlessTold) {
  const fs::path journal = dir_.path() / "treatment.lfj";
  std::string out;
  ASSERT_TRUE(sim({"--journal", journal.string()}, &out, 2).ok()) << out;
  const std::string first = contents(journal);
  EXPECT_FALSE(sim({"--journal", journal.string()}, &out).ok()) << out;
  EXPECT_NE(out.find("--overwrite"), std::string::npos) << "says how: " << out;
  EXPECT_EQ(contents(journal), first);
  ASSERT_TRUE(sim({"--journal", journal.string(), "--overwrite"}, &out, 3).ok()) << out;
  EXPECT_GT(contents(journal).size(), first.size()) << "replaced by the new run's journal when told";

  // --overwrite replaces an earlier journal, never another file, nor anything through a link.
  const fs::path notes = dir_.path() / "notes.txt", link = dir_.path() / "link.lfj";
  std::ofstream(notes) << "precious";
  fs::create_symlink(journal, link);
  const std::string second = contents(journal);
  for (const fs::path& target : {notes, link}) {
    EXPECT_FALSE(sim({"--journal", target.string(), "--overwrite"}, &out).ok()) << target << ": " << out;
    EXPECT_EQ(out.find("cycles"), std::string::npos) << "refused before the run: " << out;
  }
  EXPECT_EQ(contents(notes), "precious");
  EXPECT_EQ(contents(journal), second) << "not written through the link";
  EXPECT_TRUE(fs::is_symlink(link));
}

TEST_F(SimRecords, EachRunWritesANewTimeStampedJournalByDefault) {
  // Two runs one after the other, then two at once (the same second: one takes the -2 name).
  std::string first, second, together;
  ASSERT_TRUE(sim({}, &first, 2, dir_.path()).ok()) << first;
  ASSERT_TRUE(sim({}, &second, 2, dir_.path()).ok()) << second;
  std::string command = "cd '" + dir_.path().string() + "'";
  std::string one = std::string(" && ('") + LFTRACK_BIN_PATH + "' -q sim --scene '" +
                    (shared_->path() / "sim.yaml").string() + "' --fast --cycles 5 --lf-dir '" +
                    (shared_->path() / "lf").string() + "')";
  ASSERT_TRUE(run_process({"/bin/sh", "-c", command + " && { (true" + one + ") & (true" + one + ") ; wait; }"},
                          &together)
                  .ok())
      << together;
  std::vector<fs::path> journals;
  for (const fs::directory_entry& e : fs::directory_iterator(dir_.path() / "out" / "sim"))
    journals.push_back(e.path());
  ASSERT_EQ(journals.size(), 4u) << "every run kept its own journal\n" << together;
  for (const fs::path& j : journals) {
    EXPECT_EQ(j.filename().string().rfind("journal-", 0), 0u) << j;
    EXPECT_EQ(j.extension(), ".lfj");
    EXPECT_TRUE(first.find(j.filename().string()) != std::string::npos ||
                second.find(j.filename().string()) != std::string::npos ||
                together.find(j.filename().string()) != std::string::npos)
        << "each run says where its journal is";
    std::string exported;
    EXPECT_TRUE(run_process({LFTRACK_BIN_PATH, "journal", "export", j.string()}, &exported).ok()) << exported;
  }
}

TEST_F(SimRecords, AControlSocketOverAnyFileIsRefusedAndTheFileKept) {
  const fs::path journal = dir_.path() / "x";
  std::string out;
  EXPECT_FALSE(sim({"--control", journal.string(), "--journal", journal.string()}, &out).ok()) << out;
  EXPECT_FALSE(fs::exists(journal)) << "refused before anything was created";
  std::ofstream(journal) << "keep me";
  EXPECT_FALSE(sim({"--control", journal.string(), "--journal", ""}, &out).ok()) << out;
  EXPECT_NE(out.find("not a socket"), std::string::npos) << out;
  EXPECT_EQ(contents(journal), "keep me");
}

TEST_F(SimRecords, AnArchiveNeverMixesWithWhatIsInItsFolder) {
  const fs::path archive = dir_.path() / "seq";
  std::string out;
  ASSERT_TRUE(sim({"--journal", "", "--archive", archive.string()}, &out, 5).ok()) << out;
  EXPECT_FALSE(sim({"--journal", "", "--archive", archive.string()}, &out, 2).ok()) << "an earlier archive is there";
  EXPECT_NE(out.find("--overwrite"), std::string::npos) << out;
  ASSERT_TRUE(sim({"--journal", "", "--archive", archive.string(), "--overwrite"}, &out, 2).ok()) << out;
  int frames = 0;
  for ([[maybe_unused]] const fs::directory_entry& e : fs::directory_iterator(archive / "frames")) ++frames;
  EXPECT_EQ(frames, 4) << "two pairs of the new run, none of the five of the old one";

  // A run that is refused for another reason removes nothing of the earlier archive.
  fs::create_directories(dir_.path() / "a-directory.lfj");
  EXPECT_FALSE(sim({"--journal", (dir_.path() / "a-directory.lfj").string(), "--archive", archive.string(),
                    "--overwrite"},
                   &out, 2)
                   .ok());
  frames = 0;
  for ([[maybe_unused]] const fs::directory_entry& e : fs::directory_iterator(archive / "frames")) ++frames;
  EXPECT_EQ(frames, 4) << "the earlier archive is still whole";

  const fs::path notes = dir_.path() / "notes";
  fs::create_directories(notes);
  std::ofstream(notes / "plan.txt") << "not an archive";
  EXPECT_FALSE(sim({"--journal", "", "--archive", notes.string(), "--overwrite"}, &out, 2).ok()) << out;
  EXPECT_EQ(contents(notes / "plan.txt"), "not an archive") << "what is not ours is not removed";
}

// Issue 18, item 5: one detector cannot see depth along its central ray; the loop tracks such a
// scene only when it says so (tracking.single_view), and then warns of the blind direction.
TEST_F(SimRecords, AOneViewSceneIsNotTrackedUnlessItSaysSo) {
  std::string one = contents(shared_->path() / "sim.yaml");
  const auto b = one.find("  - name: B");
  one.erase(b, one.find("envelope:") - b);
  const fs::path refused = dir_.path() / "one.yaml", allowed = dir_.path() / "one-allowed.yaml";
  std::ofstream(refused) << one;
  one.replace(one.find("tracking:\n"), 10, "tracking:\n  single_view: true\n");
  std::ofstream(allowed) << one;
  std::string out;
  const std::vector<std::string> argv = {LFTRACK_BIN_PATH, "sim", "--fast", "--cycles", "2", "--journal", "",
                                         "--lf-dir", (dir_.path() / "lf").string(), "--scene"};
  auto with = [&](const fs::path& scene) {
    std::vector<std::string> a = argv;
    a.push_back(scene.string());
    return a;
  };
  EXPECT_FALSE(run_process(with(refused), &out).ok()) << out;
  EXPECT_NE(out.find("single_view"), std::string::npos) << "says how to allow it: " << out;
  EXPECT_EQ(out.find("cycles 2"), std::string::npos) << "nothing ran: " << out;
  EXPECT_TRUE(run_process(with(allowed), &out).ok()) << out;
  EXPECT_NE(out.find("cannot see motion along"), std::string::npos) << "names the blind direction: " << out;
}

TEST_F(SimRecords, AnOfflineRunTakesNoRealtimePriority) {
  std::string out;
  ASSERT_TRUE(sim({"--json", "--journal", ""}, &out).ok()) << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_EQ(j["realtime"].get<std::string>().rfind("not applied", 0), 0u) << j["realtime"];
}

TEST_F(SimRecords, TheChaosSoakRefusesAbsurdValuesAndNeverOverwritesAnEarlierSoak) {
  std::string out;
  const std::vector<std::vector<std::string>> usage_errors = {
      {"--chaos", "-1"},          {"--chaos", "1e12"},       {"--chaos", "nan"},
      {"--chaos", "1", "--chaos-rate", "nan"},               {"--chaos", "1", "--chaos-rate", "0.6"},
      {"--chaos", "1", "--chaos-segment", "0"},              {"--chaos", "1", "--journal", "x.lfj"},
      {"--chaos", "1", "--hil", "modbus"},                   {"--chaos-rate", "0.1"},
      {"--chaos", "1", "--chaos-out", ""},                   {"--chaos", "1", "--rt", "enforce"}};
  for (const auto& bad : usage_errors) {
    const Status s = sim(bad, &out, 3, dir_.path());
    EXPECT_NE(s.message().find("status 512"), std::string::npos) << bad[1] << ": a usage error, exit 2: " << out;
  }
  EXPECT_TRUE(fs::is_empty(dir_.path())) << "nothing created by a refused soak";

  const fs::path folder = dir_.path() / "soak";
  const std::vector<std::string> soak = {"--chaos", "7", "--chaos-segment", "40", "--chaos-rate", "0.1",
                                         "--chaos-out", folder.string(), "--json"};
  ASSERT_TRUE(sim(soak, &out, 120).ok()) << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_EQ(j["violation_count"], 0) << j.dump(1);
  EXPECT_GT(j["cycles"].get<int>(), 60);
  EXPECT_GT(j["faults_injected_total"].get<int>(), 0);
  EXPECT_GT(j["journal_records_checked"].get<int>(), 0);
  EXPECT_EQ(j["journal_dir"], (folder / "chaos-7-1").string());
  const auto journals = [&](const fs::path& run) {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(run)) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    return files;
  };
  const std::vector<fs::path> first = journals(folder / "chaos-7-1");
  ASSERT_GE(first.size(), 3u);
  const std::string first_journal = contents(first[0]);
  // The same soak again over the same folder: a folder of its own beside the first, which stays.
  ASSERT_TRUE(sim(soak, &out, 120).ok()) << out;
  EXPECT_GE(journals(folder / "chaos-7-2").size(), 3u);
  EXPECT_EQ(journals(folder / "chaos-7-1"), first);
  EXPECT_EQ(contents(first[0]), first_journal);
}

}  // namespace
}  // namespace lftrack::session
