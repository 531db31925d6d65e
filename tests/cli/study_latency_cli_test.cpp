// `lftrack study latency` (issue 56): the latency chain of a real-clock run's corrections, link by
// link, from its journal; the run's own summary and `journal export --summary` give the same
// chain; a simulated-clock journal has none and the study says why; an earlier study's files are
// never replaced.

#include <gtest/gtest.h>

#include <fstream>
#include <sstream>
#include <string>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;

namespace {

namespace fs = std::filesystem;
using test::lftrack_bin;

// The built-in scene with small fields (fast to build), as a file in `dir`. A host starved by its
// neighbours must not make the real clock's frames stale: the chain is under test, not the gate.
fs::path small_scene(const fs::path& dir) {
  std::string scene = *builtin_scene_text(kBuiltinPhantom);
  for (const std::string field :
       {"    resolution: [16, 16, 128, 128]\n", "    resolution: [24, 24, 192, 192]\n"})
    scene.replace(scene.find(field), field.size(), "    resolution: [6, 6, 48, 64]\n");
  scene.replace(scene.find("safety:\n"), 8, "safety:\n  max_frame_age_ms: 2000\n");
  const fs::path file = dir / "small.yaml";
  std::ofstream(file) << scene;
  return file;
}

nlohmann::json json_of(const std::string& out) {
  return nlohmann::json::parse(out.substr(out.find('{')));
}

TEST(StudyLatency, ARealClockRunsChainIsJournaledSummarisedAndPlottedLinkByLink) {
  test::TempDir dir;
  const fs::path scene = small_scene(dir.path());
  const fs::path journal = dir.path() / "real.lfj";
  std::string out;
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "sim", "--scene", scene.string(), "--cycles", "30", "--json",
                           "--journal", journal.string(), "--lf-dir", (dir.path() / "lf").string()},
                          &out)
                  .ok())
      << out;
  const nlohmann::json run = json_of(out);
  ASSERT_TRUE(run["latency_chain_ms"].is_object()) << run.dump();
  const int commands = run["latency_chain_ms"]["commands"].get<int>();
  EXPECT_GT(commands, 0);
  EXPECT_EQ(commands, run["latency_exposure_to_ack_ms"]["commands"].get<int>())
      << "every acknowledged command on the real clock has its whole chain";
  for (const char* link : {"arrive", "preprocess", "register", "gate", "write", "acknowledge", "total"})
    EXPECT_GE(run["latency_chain_ms"][link]["p50"].get<double>(), 0.0) << link;
  EXPECT_GT(run["latency_chain_ms"]["register"]["p50"].get<double>(), 0.0) << "a registration takes time";

  std::string figures;
  ASSERT_TRUE(run_process({lftrack_bin(), "journal", "export", journal.string(), "--summary"}, &figures).ok())
      << figures;
  EXPECT_EQ(json_of(figures)["latency_chain_ms"], run["latency_chain_ms"])
      << "the journal alone gives the same chain";

  const fs::path study = dir.path() / "study";
  std::string table;
  ASSERT_TRUE(
      run_process({lftrack_bin(), "study", "latency", journal.string(), "--out", study.string()}, &table)
          .ok())
      << table;
  for (const char* row :
       {"exposure to arrival", "preprocess", "register", "acknowledge", "exposure to acknowledgement"})
    EXPECT_NE(table.find(row), std::string::npos) << row << "\n" << table;
  // One CSV row per command, whose links add up to its total.
  std::ifstream csv(study / "chain.csv");
  std::string line;
  ASSERT_TRUE(std::getline(csv, line));
  EXPECT_EQ(line,
            "journal,cycle,arrive_ms,preprocess_ms,register_ms,gate_ms,write_ms,acknowledge_ms,total_ms");
  int rows = 0;
  while (std::getline(csv, line)) {
    std::stringstream cells(line);
    std::string cell;
    std::getline(cells, cell, ',');
    EXPECT_EQ(cell, "0") << "the one journal";
    std::getline(cells, cell, ',');  // its cycle
    double sum = 0, value = 0;
    for (int link = 0; link < 6; ++link) {
      std::getline(cells, cell, ',');
      value = std::stod(cell);
      EXPECT_GE(value, 0.0) << line;
      sum += value;
    }
    std::getline(cells, cell, ',');
    EXPECT_NEAR(std::stod(cell), sum, 5e-6) << line;
    ++rows;
  }
  EXPECT_EQ(rows, commands);
  std::ifstream summary_file(study / "summary.json");
  const nlohmann::json summary = nlohmann::json::parse(summary_file);
  EXPECT_EQ(summary["commands_with_chain"].get<int>(), commands);
  EXPECT_LE(summary["links_ms"]["register"]["p50"].get<double>(),
            summary["exposure_to_acknowledgement_ms"]["p50"].get<double>());
  EXPECT_TRUE(fs::exists(study / "latency_chain.gp"));
  // Nearest rank, as the summary's bins: the two agree within a bin (0.01 ms).
  for (const char* link : {"arrive", "register", "acknowledge"})
    for (const char* q : {"p50", "p95", "p99", "max"})
      EXPECT_NEAR(summary["links_ms"][link][q].get<double>(), run["latency_chain_ms"][link][q].get<double>(),
                  0.0101)
          << link << " " << q;
  EXPECT_NEAR(summary["exposure_to_acknowledgement_ms"]["p99"].get<double>(),
              run["latency_chain_ms"]["total"]["p99"].get<double>(), 0.0101);

  // The same journal twice, by another path too: refused, not counted twice.
  std::string twice;
  EXPECT_FALSE(
      run_process({lftrack_bin(), "study", "latency", journal.string(),
                   (dir.path() / "." / "real.lfj").string(), "--out", (dir.path() / "twice").string()},
                  &twice)
          .ok());
  EXPECT_NE(twice.find("given twice"), std::string::npos) << twice;

  // A second study into the same folder replaces nothing.
  const auto csv_time = fs::last_write_time(study / "chain.csv");
  std::string again;
  const Status second =
      run_process({lftrack_bin(), "study", "latency", journal.string(), "--out", study.string()}, &again);
  EXPECT_FALSE(second.ok());
  EXPECT_NE(again.find("exists (an earlier study's"), std::string::npos) << again;
  EXPECT_EQ(fs::last_write_time(study / "chain.csv"), csv_time);
}

TEST(StudyLatency, ASimulatedClockJournalHasNoChainAndTheStudySaysWhy) {
  test::TempDir dir;
  const fs::path scene = small_scene(dir.path());
  const fs::path journal = dir.path() / "fast.lfj";
  std::string out;
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "sim", "--scene", scene.string(), "--fast", "--cycles", "10",
                           "--json", "--journal", journal.string(), "--lf-dir", (dir.path() / "lf").string()},
                          &out)
                  .ok())
      << out;
  EXPECT_TRUE(json_of(out)["latency_chain_ms"].is_null()) << "the simulated clock's work takes no time";
  std::string said;
  EXPECT_FALSE(
      run_process({lftrack_bin(), "study", "latency", journal.string(), "--out", (dir.path() / "s").string()},
                  &said)
          .ok());
  EXPECT_NE(said.find("the simulated clock"), std::string::npos) << said;
  EXPECT_NE(said.find("none with a latency chain"), std::string::npos) << said;
  EXPECT_FALSE(fs::exists(dir.path() / "s" / "chain.csv"));
  EXPECT_EQ(said.find("exposure to acknowledgement"), std::string::npos) << "no table of zeros:\n" << said;
  // Not a journal: refused with the reader's reason.
  std::ofstream(dir.path() / "not.lfj") << "hello";
  EXPECT_FALSE(run_process({lftrack_bin(), "study", "latency", (dir.path() / "not.lfj").string(), "--out",
                            (dir.path() / "t").string()},
                           &said)
                   .ok());
}

}  // namespace
}  // namespace lftrack::session
