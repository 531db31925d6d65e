// The lftrack program as a user runs it: exit codes, messages, files written.

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <iterator>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "lftrack/studies/trade_study.hpp"
#include "lftrack/tracking/image_io.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::read_trade_shard;
using studies::run_process;
using studies::TradeResult;

namespace {

using test::lftrack_bin;

// Whether `dir` holds a light field of `view` (files VIEW-KEY.lf, scene.hpp).
bool has_light_field(const std::filesystem::path& dir, const std::string& view) {
  std::error_code ec;
  for (std::filesystem::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.rfind(view + "-", 0) == 0 && it->path().extension() == ".lf") return true;
  }
  return false;
}

TEST(Cli, DrrWritesBothViewsOfTheDefaultScene) {
  test::TempDir dir;
  std::string out;
  const Status s = run_process(
      {lftrack_bin(), "drr", "--scene", "builtin:phantom", "--renderer", "siddon", "-o", dir.path().string()},
      &out);
  ASSERT_TRUE(s.ok()) << out;
  for (const char* view : {"A", "B"}) {
    const auto png = dir.path() / ("drr_" + std::string(view) + ".png");
    const auto pfm = dir.path() / ("drr_" + std::string(view) + "_mu_mm.pfm");
    EXPECT_NE(out.find(png.string()), std::string::npos) << "prints where the files are";
    auto image = tracking::read_png(png);
    auto data = tracking::read_pfm(pfm);
    ASSERT_TRUE(image.ok() && data.ok());
    EXPECT_EQ(image->rows(), 512);
    EXPECT_EQ(data->cols(), 512);
    float hi = 0;
    for (float v : data->pixels()) hi = std::max(hi, v);
    EXPECT_GT(hi, 3.0f) << "a torso absorbs: line integrals of several mu*mm";
  }
}

TEST(Cli, BadSceneFailsWithFileLineAndReason) {
  test::TempDir dir;
  const auto file = dir.path() / "bad.yaml";
  std::ofstream(file) << "version: 1\nct: {path: builtin:phantom}\ndetectors:\n  - name: A\n    rows: -3\n";
  std::string out;
  const Status s = run_process({lftrack_bin(), "info", "--scene", file.string()}, &out);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(out.find(file.string() + ":5:"), std::string::npos) << out;
}

// Issue 50 probe: --save-frames naming a file ended in "unexpected error" (exit 3) after the CT
// load; a scene path naming /dev/zero took memory without end. Both are refused at once (exit 1).
TEST(Cli, SaveFramesOnAFileAndASceneThatIsNoFileAreRefusedAtOnce) {
  test::TempDir dir;
  const auto file = dir.path() / "notes.txt";
  std::ofstream(file) << "kept\n";
  std::string out;
  Status s = run_process({lftrack_bin(), "register", "--sim", "--save-frames", file.string()}, &out);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(out.find("not a folder"), std::string::npos) << out;
  EXPECT_EQ(out.find("unexpected error"), std::string::npos) << out;
  EXPECT_EQ(out.find("CT builtin"), std::string::npos) << "refused before the CT load: " << out;
  s = run_process({lftrack_bin(), "info", "--scene", "/dev/zero"}, &out);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(out.find("not a regular file"), std::string::npos) << out;
}

// Issue 50 probe: a light-field folder that is a file, a sequence that is not there and a token
// file that is someone's notes were refused only after the CT load (and, for the folder, minutes
// of building fields nowhere). Refused with the other options, before the CT is read.
TEST(Cli, BadFoldersAndTokenFilesAreRefusedBeforeTheCtLoad) {
  test::TempDir dir;
  const auto notes = dir.path() / "notes.txt";
  std::ofstream(notes) << "kept\n";
  const std::vector<std::vector<std::string>> runs = {
      {lftrack_bin(), "sim", "--fast", "--cycles", "1", "--journal", "", "--lf-dir", notes.string()},
      {lftrack_bin(), "replay", "--sequence", (dir.path() / "nothing").string(), "--journal", ""},
      {lftrack_bin(), "sim", "--fast", "--cycles", "1", "--journal", "", "--monitor", "127.0.0.1:0",
       "--monitor-token-file", notes.string()},
  };
  for (const auto& argv : runs) {
    std::string out;
    EXPECT_FALSE(run_process(argv, &out).ok()) << argv[1] << ": " << out;
    EXPECT_EQ(out.find("CT builtin"), std::string::npos) << "refused before the CT load: " << out;
  }
  std::ifstream in(notes);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), "kept\n");
}

TEST(Cli, UnknownViewAndRendererAreErrors) {
  test::TempDir dir;
  std::string out;
  EXPECT_FALSE(run_process({lftrack_bin(), "drr", "--view", "C", "-o", dir.path().string()}, &out).ok());
  EXPECT_NE(out.find("no view 'C'"), std::string::npos) << out;
  EXPECT_FALSE(
      run_process({lftrack_bin(), "drr", "--renderer", "magic", "-o", dir.path().string()}, &out).ok());
  EXPECT_NE(out.find("unknown renderer 'magic'"), std::string::npos) << out;
  // Usage errors exit 2 (status 512 from waitpid) with CLI11's reason; --help exits 0.
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"drr", "--bin", "abc"},
        {"no-such-command"},
        {"sim", "--cycles", "-1"},
        {"sim", "--cycles", "99999999999999999999"},  // beyond 64 bits
        {"sim", "--cycles", "2000000000"},            // beyond the 1e9 a run may ask
        {"register", "--i0", "0"},
        {"register", "--i0", "-1"},
        {"register", "--i0", "nan"},
        {"bench", "register", "--cold", "0"},  // no run would be reported as zeros
        {"bench", "register", "--cold", "-1"},
        {"bench", "register", "--warm", "-1"},
        {"bench", "register", "--siddon-runs", "-5"},
        {"drr", "--window", "nan,1"},
        {"drr", "--window", "0,inf"}}) {
    std::vector<std::string> argv = {lftrack_bin()};
    argv.insert(argv.end(), args.begin(), args.end());
    const Status s = run_process(argv, &out);
    EXPECT_NE(s.message().find("(status 512)"), std::string::npos) << args[0] << ": " << s.message() << "\n" << out;
  }
  EXPECT_TRUE(run_process({lftrack_bin(), "sim", "--help"}, &out).ok()) << out;
  // A server refuses a bad --control path before it binds its port (an outside probe saw the
  // Modbus port bound first), and leaves the file there alone.
  const auto taken = dir.path() / "control.txt";
  std::ofstream(taken) << "someone's";
  const Status serve = run_process({lftrack_bin(), "serve", "couch", "--modbus", "tcp:127.0.0.1:0", "--duration", "0.5",
                                    "--control", taken.string()},
                                   &out);
  EXPECT_NE(serve.message().find("(status 256)"), std::string::npos) << serve.message();
  EXPECT_NE(out.find("a file is there; refusing to replace it"), std::string::npos) << out;
  EXPECT_EQ(out.find("modbus tcp 127.0.0.1"), std::string::npos) << "bound before refusing: " << out;
  std::ifstream kept(taken);
  std::string word;
  kept >> word;
  EXPECT_EQ(word, "someone's");
  const Status reversed = run_process({lftrack_bin(), "drr", "--window", "5,1", "-o", dir.path().string()}, &out);
  EXPECT_NE(reversed.message().find("(status 256)"), std::string::npos) << reversed.message();
  EXPECT_NE(out.find("--window low,high needs low below high"), std::string::npos) << out;
}

// Issue 50: `serve detectors --help` gave its required --scene "(default: built-in)" and the
// couch's texts for --scene and --room. Each server's help describes what its options do for it.
TEST(Cli, EachServersHelpDescribesItsOwnOptions) {
  const auto help = [](const std::string& server) {
    std::string out;
    EXPECT_TRUE(run_process({lftrack_bin(), "serve", server, "--help"}, &out).ok()) << out;
    return out;
  };
  // An option's entry: from its name to the next option's.
  const auto entry = [](const std::string& out, const std::string& option) {
    const auto at = out.find("  " + option + " ");
    EXPECT_NE(at, std::string::npos) << option << " in " << out;
    return at == std::string::npos ? std::string() : out.substr(at, out.find("\n  -", at + 1) - at);
  };
  const std::string detectors = help("detectors");
  const std::string scene = entry(detectors, "--scene");
  EXPECT_NE(scene.find("REQUIRED"), std::string::npos) << scene;
  EXPECT_EQ(scene.find("default"), std::string::npos) << "a required option has no default: " << scene;
  EXPECT_NE(scene.find("detectors are served"), std::string::npos) << scene;
  EXPECT_NE(entry(detectors, "--room").find("Read where the served couch or robot"), std::string::npos) << detectors;
  EXPECT_NE(entry(detectors, "--fault").find("power-cycle"), std::string::npos) << detectors;
  for (const char* other : {"couch's", "robot's", "no-reply", "bus-off"})
    EXPECT_EQ(detectors.find(other), std::string::npos) << other << " in:\n" << detectors;
  const std::string couch = help("couch");
  EXPECT_NE(entry(couch, "--scene").find("the couch's dynamics"), std::string::npos) << couch;
  EXPECT_NE(entry(couch, "--fault").find("no-reply"), std::string::npos) << couch;
  const std::string robot = help("robot");
  EXPECT_NE(entry(robot, "--scene").find("the robot's dynamics"), std::string::npos) << robot;
  EXPECT_NE(entry(robot, "--room").find("the robot's position"), std::string::npos) << robot;
  EXPECT_NE(entry(robot, "--fault").find("bus-off"), std::string::npos) << robot;
  for (const char* other : {"couch's", "no-reply", "power-cycle"})
    EXPECT_EQ(robot.find(other), std::string::npos) << other << " in:\n" << robot;
}

// The built-in phantom with small light fields, written next to the test's folder.
std::filesystem::path small_light_field_scene(const std::filesystem::path& dir, const char* extra = "") {
  auto text = builtin_scene_text("builtin:phantom");
  std::string scene = *text;
  const std::string field = "    resolution: [16, 16, 128, 128]\n";
  scene.replace(scene.find(field), field.size(), "    resolution: [4, 4, 48, 48]\n    storage: fixed16\n");
  scene += extra;
  const auto file = dir / "small_lf.yaml";
  std::ofstream(file) << scene;
  return file;
}

TEST(Cli, PrecomputeThenRenderWithTheLightField) {
  test::TempDir dir;
  const auto scene = small_light_field_scene(dir.path());
  const auto lf_dir = dir.path() / "lf";
  std::string out;
  ASSERT_TRUE(
      run_process({lftrack_bin(), "precompute", "--scene", scene.string(), "-o", lf_dir.string()}, &out).ok())
      << out;
  EXPECT_TRUE(has_light_field(lf_dir, "A")) << out;
  EXPECT_TRUE(has_light_field(lf_dir, "B")) << out;
  EXPECT_NE(out.find("100%"), std::string::npos) << "a progress bar: " << out;
  ASSERT_TRUE(run_process({lftrack_bin(), "drr", "--scene", scene.string(), "--lf-dir", lf_dir.string(),
                           "--roi", "-o", (dir.path() / "drr").string()},
                          &out)
                  .ok())
      << out;
  auto data = tracking::read_pfm(dir.path() / "drr" / "drr_A_mu_mm.pfm");
  ASSERT_TRUE(data.ok());
  float hi = 0;
  for (float v : data->pixels()) hi = std::max(hi, v);
  EXPECT_GT(hi, 3.0f);
}

TEST(Cli, LightFieldsForAnotherSceneAreRefused) {
  test::TempDir dir;
  const auto lf_dir = dir.path() / "lf";
  std::string out;
  ASSERT_TRUE(run_process({lftrack_bin(), "precompute", "--scene",
                           small_light_field_scene(dir.path()).string(), "-o", lf_dir.string()},
                          &out)
                  .ok())
      << out;
  // The same scene with a wider envelope: the fields no longer cover it.
  const auto wider = small_light_field_scene(dir.path());
  std::string text;
  {
    std::ifstream in(wider);
    text.assign(std::istreambuf_iterator<char>(in), {});
  }
  text.replace(text.find("rotation_deg: 5"), std::string("rotation_deg: 5").size(), "rotation_deg: 6");
  std::ofstream(wider) << text;
  EXPECT_FALSE(run_process({lftrack_bin(), "drr", "--scene", wider.string(), "--lf-dir", lf_dir.string(),
                            "-o", (dir.path() / "drr").string()},
                           &out)
                   .ok());
  EXPECT_NE(out.find("no light field of view A for these settings"), std::string::npos) << out;
  EXPECT_NE(out.find("envelope rotation_deg (5 in the file, 6 now)"), std::string::npos) << out;
  // No fields at all: the message says what to run.
  EXPECT_FALSE(run_process({lftrack_bin(), "drr", "--scene", wider.string(), "--lf-dir",
                            (dir.path() / "none").string(), "-o", (dir.path() / "drr").string()},
                           &out)
                   .ok());
  EXPECT_NE(out.find("lftrack precompute"), std::string::npos) << out;
}

TEST(Cli, BenchDrrJsonHasTheDocumentedFields) {
  test::TempDir dir;
  std::string out;
  const Status s = run_process(
      {lftrack_bin(), "-q", "bench", "drr", "--scene", small_light_field_scene(dir.path()).string(), "--size",
       "24", "--poses", "1", "--repeats", "1", "--vq-codebooks", "16", "--json"},
      &out);
  ASSERT_TRUE(s.ok()) << out;
  const auto json = nlohmann::json::parse(out.substr(out.find('{')));
  for (const char* key : {"ct", "size", "renderers", "peers", "light_field"})
    EXPECT_TRUE(json.contains(key)) << key;
  std::vector<std::string> names;
  for (const auto& r : json["renderers"]) {
    names.push_back(r["name"]);
    for (const char* key : {"name", "ms_median", "speedup_vs_siddon", "ncc_vs_siddon", "psnr_db_vs_siddon",
                            "bytes", "out_of_field_fraction"})
      EXPECT_TRUE(r.contains(key)) << key;
  }
  for (const char* name :
       {"siddon", "trilinear", "lightfield-float", "lightfield-float-per-ray", "lightfield-fixed16", "lightfield-vq16"})
    EXPECT_NE(std::find(names.begin(), names.end(), name), names.end()) << name;
  for (const auto& p : json["peers"])
    for (const char* key : {"name", "ms_median", "ncc_vs_siddon"}) EXPECT_TRUE(p.contains(key)) << key;
  // With plastimatch installed, every light field is also timed beside each plastimatch run.
  if (!json["peers"].empty()) {
    for (const auto& r : json["renderers"]) {
      if (r["name"].get<std::string>().rfind("lightfield", 0) != 0) continue;
      ASSERT_TRUE(r.contains("speedup_vs_plastimatch_side_by_side")) << r["name"];
      EXPECT_GT(r["speedup_vs_plastimatch_side_by_side"].get<double>(), 0.0) << r["name"];
    }
  }
}

}  // namespace
}  // namespace lftrack::session

namespace lftrack::session {
namespace {

// The built-in scene with a coarse light field (built in a moment) for command tests.
std::filesystem::path small_light_field_scene(const test::TempDir& dir) {
  const auto file = dir.path() / "phantom-small-lf.yaml";
  std::ofstream(file) << test::coarse_phantom_scene_text();
  return file;
}

TEST(Cli, RegisterSimulatedFramesPrintsPoseSimilarityAndTre) {
  test::TempDir dir;
  const auto scene = small_light_field_scene(dir);
  std::string out;
  const Status s =
      run_process({lftrack_bin(), "-q", "register", "--scene", scene.string(), "--sim", "--gold",
                   "1,-1,0.5,0.5,0,-0.5", "--init", "-2,2,-1.5,-1,1,1", "--lf-dir",
                   (dir.path() / "lf").string(), "--save-frames", (dir.path() / "frames").string(), "--json"},
                  &out);
  ASSERT_TRUE(s.ok()) << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_EQ(j["views"].size(), 2u);
  EXPECT_GT(j["evaluations"].get<int>(), 12);
  EXPECT_GT(j["initial_tre_mm"]["mean"].get<double>(), 3.0);
  EXPECT_LT(j["tre_mm"]["mean"].get<double>(), 1.0) << out;
  EXPECT_TRUE(has_light_field(dir.path() / "lf", "A")) << "a missing field is built and kept";

  // The saved frames register from files the same way.
  std::string again;
  const Status f =
      run_process({lftrack_bin(), "-q", "register", "--scene", scene.string(), "--frames",
                   (dir.path() / "frames" / "frame_A.tif").string(),
                   (dir.path() / "frames" / "frame_B.tif").string(), "--gold", "1,-1,0.5,0.5,0,-0.5",
                   "--init", "-2,2,-1.5,-1,1,1", "--lf-dir", (dir.path() / "lf").string(), "--json"},
                  &again);
  ASSERT_TRUE(f.ok()) << again;
  const auto k = nlohmann::json::parse(again.substr(again.find('{')));
  EXPECT_NEAR(k["tre_mm"]["mean"].get<double>(), j["tre_mm"]["mean"].get<double>(), 1e-9);
}

TEST(Cli, RegisterRefusesBadInput) {
  test::TempDir dir;
  const auto scene = small_light_field_scene(dir);
  std::string out;
  EXPECT_FALSE(run_process({lftrack_bin(), "register", "--scene", scene.string()}, &out).ok());
  EXPECT_NE(out.find("either --frames A B or --sim"), std::string::npos) << out;
  const auto junk = dir.path() / "junk.tif";
  std::ofstream(junk) << "not a tiff";
  EXPECT_FALSE(run_process({lftrack_bin(), "register", "--scene", scene.string(), "--frames", junk.string(),
                            junk.string()},
                           &out)
                   .ok());
  EXPECT_FALSE(
      run_process({lftrack_bin(), "register", "--scene", scene.string(), "--sim", "--plan", "fast"}, &out)
          .ok());
  EXPECT_NE(out.find("unknown registration plan"), std::string::npos) << out;
}

TEST(Cli, CaptureRangeStudyWritesCsvSummaryAndPlot) {
  test::TempDir dir;
  const auto scene = small_light_field_scene(dir);
  std::string out;
  const auto study = dir.path() / "study";
  const Status s = run_process({lftrack_bin(), "-q", "study", "capture-range", "--scene", scene.string(),
                                "--out", study.string(), "--per-bin", "2", "--bins", "2", "--methods",
                                "warm:ncc,papers:mi", "--lf-dir", (dir.path() / "lf").string()},
                               &out);
  ASSERT_TRUE(s.ok()) << out;
  std::ifstream csv(study / "runs.csv");
  const long lines = std::count(std::istreambuf_iterator<char>(csv), std::istreambuf_iterator<char>(), '\n');
  EXPECT_EQ(lines, 1 + 2 * 2 * 2);
  std::ifstream summary_file(study / "summary.json");
  const auto summary = nlohmann::json::parse(summary_file);
  ASSERT_EQ(summary["methods"].size(), 2u);
  for (const auto& m : summary["methods"])
    for (const char* key :
         {"name", "success_rate", "mean_tre_mm", "max_tre_mm", "capture_range_mm", "median_ms"})
      EXPECT_TRUE(m.contains(key)) << key;
  EXPECT_TRUE(std::filesystem::exists(study / "capture_range.gp"));
  if (std::system("command -v gnuplot >/dev/null 2>&1") == 0) {
    EXPECT_GT(std::filesystem::file_size(study / "capture_range.png"), 1000u);
  }
  EXPECT_FALSE(run_process({lftrack_bin(), "study", "capture-range", "--scene", scene.string(), "--out",
                            study.string(), "--methods", "papers:entropy"},
                           &out)
                   .ok());
  EXPECT_NE(out.find("unknown similarity"), std::string::npos) << out;
}

// The trade study sharded in two and merged, on the small scene with one problem per point (the
// octree's registration takes half a minute here): the octree registers on its decompressed
// volume, the light field at its baseline and binned.
TEST(Cli, TradeStudyShardsMergeIntoPlotsAndASummary) {
  test::TempDir dir;
  const auto scene = small_light_field_scene(dir.path());
  std::string out;
  const std::vector<std::string> common = {lftrack_bin(),
                                           "-q",
                                           "study",
                                           "trade",
                                           "--scene",
                                           scene.string(),
                                           "--quick",
                                           "--problems",
                                           "1",
                                           "--points",
                                           "baseline,bin2,octree-P0.02"};
  for (const char* shard : {"1/2", "2/2"}) {
    auto args = common;
    args.insert(args.end(),
                {"--shard", shard, "--out", (dir.path() / ("shard" + std::string(1, shard[0]))).string()});
    ASSERT_TRUE(run_process(args, &out).ok()) << out;
  }
  const auto merged = dir.path() / "merged";
  ASSERT_TRUE(run_process({lftrack_bin(), "study", "merge", "--out", merged.string(),
                           (dir.path() / "shard1").string(), (dir.path() / "shard2").string()},
                          &out)
                  .ok())
      << out;
  auto study = read_trade_shard(merged);
  ASSERT_TRUE(study.ok()) << study.status().message();
  ASSERT_EQ(study->results.size(), 3u);
  for (const TradeResult& r : study->results) {
    EXPECT_EQ(r.runs, 1) << r.point.id;
    EXPECT_GT(r.median_ms, 0) << r.point.id;
    EXPECT_GT(r.memory_bytes, 0) << r.point.id;
    EXPECT_LT(r.mean_tre_mm, 1.0) << r.point.id << ": every point registers the small scene's problems";
    // The small scene's field is 4 x 4 x 48 x 48 in 16 bits; the octree is near exact.
    EXPECT_GT(r.ncc_vs_siddon, r.point.renderer == "octree" ? 0.999 : 0.95) << r.point.id;
  }
  std::ifstream md(merged / "summary.md");
  const std::string summary((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
  EXPECT_NE(summary.find("## Recommended defaults"), std::string::npos);
  if (std::system("command -v gnuplot >/dev/null 2>&1") == 0) {
    EXPECT_GT(std::filesystem::file_size(merged / "tre_vs_time.png"), 1000u);
    EXPECT_GT(std::filesystem::file_size(merged / "memory_vs_fidelity.png"), 1000u);
  }
  // A second merge into the first one's folder replaces nothing.
  const auto merged_summary_time = std::filesystem::last_write_time(merged / "summary.md");
  EXPECT_FALSE(run_process({lftrack_bin(), "study", "merge", "--out", merged.string(), (dir.path() / "shard1").string(),
                            (dir.path() / "shard2").string()},
                           &out)
                   .ok());
  EXPECT_NE(out.find("is not empty"), std::string::npos) << out;
  EXPECT_EQ(std::filesystem::last_write_time(merged / "summary.md"), merged_summary_time);
  // A missing shard and a bad shard spec are refused.
  EXPECT_FALSE(run_process({lftrack_bin(), "study", "merge", "--out", (dir.path() / "merged-half").string(),
                            (dir.path() / "shard1").string()},
                           &out)
                   .ok());
  EXPECT_NE(out.find("shard 2 of 2 is missing"), std::string::npos) << out;
  auto bad = common;
  bad.insert(bad.end(), {"--shard", "3/2", "--out", "x"});
  EXPECT_FALSE(run_process(bad, &out).ok());
  EXPECT_NE(out.find("1 <= k <= n"), std::string::npos) << out;
  auto unknown = common;
  unknown.back() = "no-such-point";
  unknown.push_back("--out");
  unknown.push_back((dir.path() / "x").string());
  EXPECT_FALSE(run_process(unknown, &out).ok());
  EXPECT_NE(out.find("no point 'no-such-point'"), std::string::npos) << out;
}

}  // namespace
}  // namespace lftrack::session

namespace lftrack::session {
namespace {

TEST(Cli, SimPrintsTheJsonSummaryWritesTheJournalAndArchivesForReplay) {
  test::TempDir dir;
  std::string scene = test::tiny_field_phantom_scene_text();
  const auto file = dir.path() / "sim.yaml";
  std::ofstream(file) << scene;
  const auto journal = dir.path() / "j.lfj";
  std::string out;
  const Status s = run_process({lftrack_bin(), "-q", "sim", "--scene", file.string(), "--fast", "--cycles",
                                "20", "--json", "--journal", journal.string(), "--lf-dir",
                                (dir.path() / "lf").string(), "--archive", (dir.path() / "seq").string()},
                               &out);
  ASSERT_TRUE(s.ok()) << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_EQ(j["cycles"].get<int>(), 20);
  for (const char* key : {"mean", "p95", "max"}) EXPECT_TRUE(j["residual_mm"][key].is_number()) << key;
  for (const char* key : {"p50", "p95", "p99", "max"}) EXPECT_TRUE(j["cycle_ms"][key].is_number()) << key;
  for (const char* key : {"overruns", "holds", "faults", "allocations_per_cycle"})
    EXPECT_TRUE(j[key].is_number()) << key;
  int cycles_in_states = 0;
  for (const char* state : {"IDLE", "ALIGN", "TRACK", "HOLD", "FAULT"})
    cycles_in_states += j["states"][state].get<int>();
  EXPECT_EQ(cycles_in_states, 20);
  EXPECT_TRUE(j["aligned"].get<bool>());
  EXPECT_EQ(j["plans"]["align"], "quadratic");  // the built-in scene names its plans
  EXPECT_EQ(j["plans"]["track"], "warm");
  EXPECT_EQ(j["plans"]["similarity"], "mi");
  std::string exported;
  ASSERT_TRUE(run_process({lftrack_bin(), "journal", "export", journal.string(), "--csv"}, &exported).ok());
  EXPECT_EQ(std::count(exported.begin(), exported.end(), '\n'), 21) << "a header and one line per cycle";
  EXPECT_EQ(j["archive"]["pairs_written"].get<int>(), 20);
  // The clinic's figures: the target per room axis and the latency to the couch's
  // acknowledgement; the journal's export computes them with the run's own accumulator, so the
  // journal alone gives the same figures.
  ASSERT_TRUE(j["target_residual"].is_object()) << j.dump();
  EXPECT_EQ(j["target_residual"]["translation_mm"]["mean"].size(), 3u);
  EXPECT_LE(j["target_residual"]["share_over_2mm"].get<double>(), 1.0);
  ASSERT_TRUE(j["latency_exposure_to_ack_ms"].is_object()) << j.dump();
  EXPECT_GT(j["latency_exposure_to_ack_ms"]["commands"].get<int>(), 0);
  std::string figures;
  ASSERT_TRUE(run_process({lftrack_bin(), "journal", "export", journal.string(), "--summary"}, &figures).ok())
      << figures;
  const auto f = nlohmann::json::parse(figures.substr(figures.find('{')));
  EXPECT_EQ(f["target_residual"], j["target_residual"]);
  for (const char* key : {"commands", "p50", "p95", "p99", "max"})
    EXPECT_EQ(f["latency_exposure_to_ack_ms"][key], j["latency_exposure_to_ack_ms"][key]) << key;
  EXPECT_NE(j["latency_exposure_to_ack_ms"].value("clock", "").find("simulated"), std::string::npos)
      << "a --fast run's latency is said to be the modelled one";
  EXPECT_EQ(f["damaged"], false);
  EXPECT_EQ(f["states"]["TRACK"], j["states"]["TRACK"]);

  // The archive replays through the same loop, with the same summary plus the replay's counts.
  std::string replayed;
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "replay", "--scene", file.string(), "--sequence",
                           (dir.path() / "seq").string(), "--fast", "--json", "--journal",
                           (dir.path() / "r.lfj").string(), "--lf-dir", (dir.path() / "lf").string()},
                          &replayed)
                  .ok())
      << replayed;
  const auto r = nlohmann::json::parse(replayed.substr(replayed.find('{')));
  EXPECT_EQ(r["cycles"].get<int>(), 20);
  EXPECT_EQ(r["ended"].get<std::string>(), "end of the sequence");
  EXPECT_EQ(r["replay"]["pairs_delivered"].get<int>(), 20);
  EXPECT_EQ(r["replay"]["missing_frames"].get<int>(), 0);
  EXPECT_TRUE(r["residual_mm"]["mean"].is_null()) << "no truth in a replay";
  EXPECT_TRUE(r["target_residual"].is_null()) << "no truth in a replay";
  EXPECT_TRUE(r["latency_exposure_to_ack_ms"].is_null()) << "a replay sends nothing";
  EXPECT_EQ(r["states"]["TRACK"].get<int>(), 20);
  EXPECT_FALSE(run_process({lftrack_bin(), "replay", "--scene", file.string(), "--sequence",
                            (dir.path() / "nothing").string()},
                           &out)
                   .ok());
  EXPECT_NE(out.find("no such sequence directory"), std::string::npos) << out;

  // `run` on V4L2 detectors that are not there: the start-up checks list every reason (the
  // device, and the missing detector calibrations), and nothing starts.
  std::string v4l2 = scene;
  for (char name : {'A', 'B'})
    v4l2.replace(v4l2.find("frames: sim"), 11,
                 std::string("frames: {type: v4l2, device: /dev/v4l/by-path/lftrack-test-absent-") + name + "}");
  if (const std::size_t at = v4l2.find("type: virtual"); at != std::string::npos) v4l2.replace(at, 13, "type: none");
  std::ofstream(dir.path() / "v4l2.yaml") << v4l2;
  EXPECT_FALSE(
      run_process({lftrack_bin(), "run", "--scene", (dir.path() / "v4l2.yaml").string(), "--rt", "ignore"},
                  &out)
          .ok());
  EXPECT_NE(out.find("refuses to start"), std::string::npos) << out;
  EXPECT_NE(out.find("lftrack-test-absent"), std::string::npos) << "the device that did not open: " << out;
  EXPECT_NE(out.find("detector calibration of A: none named"), std::string::npos) << out;
  EXPECT_NE(out.find("detector calibration of B: none named"), std::string::npos) << out;
  // The short form names no device: refused at load, with the line.
  std::string short_form = scene;
  short_form.replace(short_form.find("frames: sim"), 11, "frames: v4l2");
  std::ofstream(dir.path() / "v4l2-short.yaml") << short_form;
  EXPECT_FALSE(run_process({lftrack_bin(), "run", "--scene", (dir.path() / "v4l2-short.yaml").string()}, &out).ok());
  EXPECT_NE(out.find("v4l2 needs its device"), std::string::npos) << out;
}

}  // namespace
}  // namespace lftrack::session
