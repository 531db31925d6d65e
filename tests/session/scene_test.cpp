#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "lftrack/session/commissioning_file.hpp"
#include "lftrack/session/scene.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

TEST(Scene, BuiltinPhantomParses) {
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_TRUE(scene->ct.is_builtin_phantom());
  ASSERT_EQ(scene->detectors.size(), 2u);
  const auto& a = scene->detectors[0].view;
  const auto& b = scene->detectors[1].view;
  EXPECT_EQ(a.rows, 512);
  EXPECT_EQ(a.cols, 512);
  EXPECT_DOUBLE_EQ(a.pitch_row_mm, 0.4);
  EXPECT_EQ(scene->detectors[0].bits, 12);
  // Orthogonal views.
  EXPECT_NEAR(a.detector_normal().dot(b.detector_normal()), 0.0, 1e-6);
}

const char* kValidScene = R"(version: 1
ct:
  path: ct_folder
roi:
  centre_mm: [0, 0, 0]
  size_mm: [40, 40, 40]
detectors:
  - name: A
    rows: 64
    cols: 64
    pitch_mm: 0.4
    isocentric:
      source_direction: [0, -1, 0]
      up: [0, 0, 1]
      source_to_isocentre_mm: 1000
      source_to_detector_mm: 1500
)";

TEST(Scene, RelativeCtPathIsResolvedAgainstTheSceneFolder) {
  auto scene = parse_scene(kValidScene, "room.yaml", "/data/scenes");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->ct.path, "/data/scenes/ct_folder");
}

TEST(Scene, ExplicitGeometryForm) {
  const std::string text = R"(version: 1
ct: {path: /ct}
roi: {centre_mm: [0, 0, 0]}
detectors:
  - name: A
    rows: 10
    cols: 20
    pitch_mm: [0.5, 0.25]
    source_mm: [0, -1000, 0]
    pixel00_mm: [-2.5, 500, 2.25]
    col_axis: [1, 0, 0]
    row_axis: [0, 0, -1]
)";
  auto scene = parse_scene(text, "s.yaml", "/");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  const auto& v = scene->detectors[0].view;
  EXPECT_DOUBLE_EQ(v.pitch_row_mm, 0.5);
  EXPECT_DOUBLE_EQ(v.pitch_col_mm, 0.25);
  EXPECT_NEAR(v.source_to_detector_mm(), 1500, 1e-9);
}

// Each class of scene error: where it is reported (file:line) and why.
struct BadScene {
  const char* name;
  const char* find;      // text in kValidScene to replace
  const char* replace;   // with this
  const char* location;  // expected "file:line" prefix
  const char* reason;    // expected text in the message
};

const BadScene kBadScenes[] = {
    {"YamlSyntax", "  size_mm: [40, 40, 40]", "  size_mm: [40, 40", "bad.yaml:", "YAML syntax error"},
    {"UnknownTopLevelKey", "detectors:", "detector:", "bad.yaml:7:", "unknown key 'detector'"},
    {"UnknownNestedKey", "    rows: 64", "    rowz: 64", "bad.yaml:9:", "unknown key 'rowz'"},
    {"MissingVersion", "version: 1\n", "", "bad.yaml:1:", "needs 'version'"},
    {"WrongVersion", "version: 1", "version: 7", "bad.yaml:1:", "version must be in 1..1"},
    {"MissingCtPath", "  path: ct_folder", "  seed: 3", "bad.yaml:", "needs 'path'"},
    {"NegativePitch", "pitch_mm: 0.4", "pitch_mm: -0.4", "bad.yaml:11:", "must be positive"},
    {"NotANumber", "source_to_isocentre_mm: 1000", "source_to_isocentre_mm: far",
     "bad.yaml:15:", "must be a number"},
    {"RowsNotInteger", "rows: 64", "rows: 6.5", "bad.yaml:9:", "must be an integer"},
    {"RowsOutOfRange", "rows: 64", "rows: 0", "bad.yaml:9:", "must be in 1..16384"},
    {"SourceBeyondDetector", "source_to_detector_mm: 1500", "source_to_detector_mm: 900",
     "bad.yaml:13:", "source-to-isocentre"},
    {"UpAlongBeam", "up: [0, 0, 1]", "up: [0, 1, 0]", "bad.yaml:13:", "parallel to the beam"},
    {"ZeroVector", "source_direction: [0, -1, 0]", "source_direction: [0, 0, 0]",
     "bad.yaml:13:", "zero vector"},
    {"VectorOfTwo", "source_direction: [0, -1, 0]", "source_direction: [0, -1]",
     "bad.yaml:13:", "list of 3 numbers"},
    {"MissingGeometry", "    isocentric:", "    isocentricx:", "bad.yaml:12:", "unknown key 'isocentricx'"},
    {"FileCtWithoutRoi", "roi:\n  centre_mm: [0, 0, 0]\n  size_mm: [40, 40, 40]\n", "",
     "bad.yaml:1:", "needs 'roi'"},
    {"UnknownFrames", "    rows: 64", "    frames: camera\n    rows: 64",
     "bad.yaml:9:", "(known: sim, v4l2, gige, replay)"},
    {"UnknownBuiltin", "  path: ct_folder", "  path: builtin:knee", "bad.yaml:3:", "unknown built-in CT"},
    {"NegativeRoiSize", "size_mm: [40, 40, 40]", "size_mm: [40, -4, 40]", "bad.yaml:6:", "must be positive"},
    // A complex key (fuzz_calibration_files found that it threw out of check_keys and aborted).
    {"ComplexKey", "version: 1\n", "version: 1\n? [a, b]\n: 1\n", "bad.yaml:2:", "a key in the scene must be a plain name"},
    // Absurd numbers a typo makes: refused with the line, never obeyed.
    {"HugeEnvelope", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nenvelope:\n  translation_mm: 1e9\n", "bad.yaml:18:",
     "envelope.translation_mm must be at most 50"},
    {"HugeTotalCorrection", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsafety:\n  max_total_mm: 1e9\n", "bad.yaml:18:",
     "safety.max_total_mm must be at most 50"},
    {"HugeStep", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsafety:\n  max_step_deg: 1e12\n", "bad.yaml:18:",
     "safety.max_step_deg must be at most 10"},
    {"StepBeyondTotal", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsafety:\n  max_step_mm: 8\n  max_total_mm: 5\n", "bad.yaml:18:",
     "max_step_mm must not exceed safety.max_total_mm"},
    {"SimilarityFloorThatPassesAnything", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsafety:\n  min_similarity: -1e12\n", "bad.yaml:18:",
     "the floor would pass frames that match nothing"},
    {"NanLimit", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsafety:\n  readback_tolerance_mm: .nan\n", "bad.yaml:18:",
     "must be finite"},
    {"HugeBreathing", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nmotion:\n  breathing: {amplitude_mm: [0, 0, 1e12]}\n", "bad.yaml:18:",
     "motion.breathing amplitudes must stay within 50 mm and 10 degrees per axis"},
    {"HugeDrift", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nmotion:\n  drift: {translation_mm_per_s: [1e300, 0, 0]}\n", "bad.yaml:18:",
     "motion.drift (per second) must stay within 10 mm"},
    {"HugePhotons", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsim:\n  photons_per_pixel: 1e40\n", "bad.yaml:18:",
     "sim.photons_per_pixel must be at most 1e+09"},
    {"UnknownExposure", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsim:\n  exposure: auto\n", "bad.yaml:18:", "(known: aec, fixed)"},
    {"AecLevelOfNothing", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsim:\n  aec_level: 0\n", "bad.yaml:18:",
     "sim.aec_level must be from 0.01 to 0.8"},
    {"AecLevelNan", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsim:\n  aec_level: .nan\n", "bad.yaml:18:", "sim.aec_level"},
    {"AecLevelAboveTheRange", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\nsim:\n  aec_level: 1e12\n", "bad.yaml:18:",
     "sim.aec_level must be from 0.01 to 0.8"},
    {"LightFieldOf16GiB", "      source_to_detector_mm: 1500\n",
     "      source_to_detector_mm: 1500\ntracking:\n  light_field:\n    resolution: [64, 64, 1024, 1024]\n",
     "bad.yaml:19:", "is 4294967296 samples: 16.0 GiB per view to build, more than the 4 GiB allowed"},
};

void PrintTo(const BadScene& c, std::ostream* os) {
  *os << c.name;
}

class BadScenes : public ::testing::TestWithParam<BadScene> {};

TEST_P(BadScenes, FailAtLoadWithLineAndReason) {
  std::string text = kValidScene;
  const auto at = text.find(GetParam().find);
  ASSERT_NE(at, std::string::npos) << GetParam().find;
  text.replace(at, std::string(GetParam().find).size(), GetParam().replace);
  auto scene = parse_scene(text, "bad.yaml", "/");
  ASSERT_FALSE(scene.ok());
  const std::string& m = scene.status().message();
  EXPECT_EQ(m.rfind(GetParam().location, 0), 0u) << m;
  EXPECT_NE(m.find(GetParam().reason), std::string::npos) << m;
}

INSTANTIATE_TEST_SUITE_P(EveryClass, BadScenes, ::testing::ValuesIn(kBadScenes),
                         [](const auto& p) { return std::string(p.param.name); });

// How far the patient may still be from place with the beam on: its own keys, not the step limit.
TEST(Scene, TheBeamsTravelLimits) {
  auto defaults = parse_scene(std::string(kValidScene), "s.yaml", "/");
  ASSERT_TRUE(defaults.ok()) << defaults.status().message();
  EXPECT_EQ(defaults->safety.beam_tolerance_mm, 2.0);
  EXPECT_EQ(defaults->safety.beam_tolerance_deg, 2.0);
  auto set = parse_scene(std::string(kValidScene) +
                             "safety:\n  max_step_mm: 10\n  max_total_mm: 20\n  beam_tolerance_mm: 1.5\n"
                             "  beam_tolerance_deg: 0.5\n",
                         "s.yaml", "/");
  ASSERT_TRUE(set.ok()) << set.status().message();
  EXPECT_EQ(set->safety.max_step_mm, 10.0);
  EXPECT_EQ(set->safety.beam_tolerance_mm, 1.5);
  EXPECT_EQ(set->safety.beam_tolerance_deg, 0.5);
  for (const char* bad : {"  beam_tolerance_mm: 0\n", "  beam_tolerance_mm: -1\n",
                          "  beam_tolerance_mm: .nan\n", "  beam_tolerance_mm: .inf\n",
                          "  beam_tolerance_mm: 11\n", "  beam_tolerance_deg: 1e12\n",
                          "  beam_tolerance_deg: near\n"}) {
    auto s = parse_scene(std::string(kValidScene) + "safety:\n" + bad, "s.yaml", "/");
    ASSERT_FALSE(s.ok()) << bad;
    EXPECT_EQ(s.status().message().rfind("s.yaml:18:", 0), 0u) << s.status().message();
    EXPECT_NE(s.status().message().find("safety.beam_tolerance_"), std::string::npos) << s.status().message();
  }
}

// How long the beam may be kept off before the loop holds (a couch that never arrives).
TEST(Scene, TheLongestTheBeamIsWithheld) {
  auto defaults = parse_scene(std::string(kValidScene), "s.yaml", "/");
  ASSERT_TRUE(defaults.ok()) << defaults.status().message();
  EXPECT_EQ(defaults->safety.max_beam_withheld_s, 10.0);
  auto set = parse_scene(std::string(kValidScene) + "safety:\n  max_beam_withheld_s: 3.5\n", "s.yaml", "/");
  ASSERT_TRUE(set.ok()) << set.status().message();
  EXPECT_EQ(set->safety.max_beam_withheld_s, 3.5);
  for (const char* bad : {"  max_beam_withheld_s: 0\n", "  max_beam_withheld_s: -1\n", "  max_beam_withheld_s: .nan\n",
                          "  max_beam_withheld_s: .inf\n", "  max_beam_withheld_s: 601\n",
                          "  max_beam_withheld_s: 1e12\n", "  max_beam_withheld_s: [1]\n",
                          "  max_beam_withheld_s: 0.05\n"}) {
    auto s = parse_scene(std::string(kValidScene) + "safety:\n" + bad, "s.yaml", "/");
    ASSERT_FALSE(s.ok()) << bad;
    EXPECT_NE(s.status().message().find("safety.max_beam_withheld_s"), std::string::npos) << s.status().message();
  }
}

TEST(Scene, LightFieldSettings) {
  std::string text = kValidScene;
  text +=
      "tracking:\n  renderer: lightfield\n  light_field:\n    resolution: [8, 8, 64, 32]\n    storage: vq\n"
      "    codebook: 1024\n    margin: 0.1\n    integration: slices\n    slice_step_mm: 0.5\n"
      "    skip_air_below_hu: -900\n";
  auto scene = parse_scene(text, "lf.yaml", "/");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->renderer, "lightfield");
  EXPECT_EQ(scene->light_field.resolution, (std::array<int, 4>{8, 8, 64, 32}));
  EXPECT_EQ(scene->light_field.storage, tracking::LightFieldStorage::kVq);
  EXPECT_EQ(scene->light_field.vq_codebook_size, 1024);
  EXPECT_DOUBLE_EQ(scene->light_field.margin_fraction, 0.1);
  EXPECT_EQ(scene->light_field.integration, tracking::LightFieldIntegration::kSlices);
  EXPECT_DOUBLE_EQ(scene->light_field.slice_step_mm, 0.5);
  EXPECT_DOUBLE_EQ(scene->light_field.skip_air_below_hu, -900);
  auto plain = parse_scene(std::string(kValidScene), "lf.yaml", "/");
  ASSERT_TRUE(plain.ok());
  EXPECT_EQ(plain->light_field.integration, tracking::LightFieldIntegration::kSiddon);
  EXPECT_EQ(plain->light_field.slice_step_mm, 0.0);
  EXPECT_EQ(plain->light_field.skip_air_below_hu, -1000.0) << "the whole grid by default";
  for (const char* bad :
       {"    storage: jpeg\n", "    resolution: [8, 8, 64]\n", "    resolution: [8, 8, 64, 1]\n",
        "    codebook: 70000\n", "    margin: 2\n", "    colour: red\n", "    integration: joseph\n",
        "    integration: [slices]\n", "    slice_step_mm: 0\n", "    slice_step_mm: -1\n",
        "    slice_step_mm: .nan\n", "    slice_step_mm: .inf\n", "    slice_step_mm: 1e12\n",
        "    slice_step_mm: fine\n", "    skip_air_below_hu: -1001\n", "    skip_air_below_hu: 0\n",
        "    skip_air_below_hu: .nan\n", "    skip_air_below_hu: -1e12\n"}) {
    const std::string t = std::string(kValidScene) + "tracking:\n  light_field:\n" + bad;
    auto s2 = parse_scene(t, "lf.yaml", "/");
    ASSERT_FALSE(s2.ok()) << bad;
    EXPECT_EQ(s2.status().message().rfind("lf.yaml:19:", 0), 0u) << s2.status().message();
  }
}

TEST(Scene, RegistrationFiducialAndSimSettings) {
  std::string text = kValidScene;
  text +=
      "tracking:\n  renderer: octree\n  octree_pivot: 0.02\n  similarity: gc\n  plan: cmaes\n"
      "  histogram_bins: 48\n  gamma_per_mm: 0.1\n  tre_box_mm: 30\nfiducials:\n  positions_mm: [[1, 2, 3], "
      "[4, 5, 6]]\n  radius_mm: 1.5\n"
      "  insert: true\nsim:\n  photons_per_pixel: 5000\n  detector_blur_px: 1\n";
  auto scene = parse_scene(text, "reg.yaml", "/");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->registration.similarity, "gc");
  EXPECT_EQ(scene->renderer, "octree");
  EXPECT_DOUBLE_EQ(scene->octree_pivot, 0.02);
  EXPECT_EQ(scene->registration.plan, "cmaes");
  EXPECT_EQ(scene->registration.histogram_bins, 48);
  EXPECT_DOUBLE_EQ(scene->registration.gamma_per_mm, 0.1);
  EXPECT_DOUBLE_EQ(scene->registration.tre_box_mm, 30);
  ASSERT_EQ(scene->fiducials.positions_ct_mm.size(), 2u);
  EXPECT_EQ(scene->fiducials.positions_ct_mm[1], Eigen::Vector3d(4, 5, 6));
  EXPECT_TRUE(scene->fiducials.insert);
  EXPECT_DOUBLE_EQ(scene->sim.photons_per_pixel, 5000);
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"tracking:\n  similarity: entropy\n", "unknown tracking.similarity 'entropy'"},
      {"tracking:\n  plan: fast\n", "unknown tracking.plan 'fast'"},
      {"tracking:\n  histogram_bins: 2\n", "must be in 4..1024"},
      {"tracking:\n  gamma_per_mm: -1\n", "must be >= 0"},
      {"tracking:\n  octree_pivot: 1.5\n", "octree_pivot must be in [0, 1]"},
      {"fiducials:\n  radius_mm: 1\n", "needs 'positions_mm'"},
      {"fiducials:\n  positions_mm: [[1, 2]]\n", "list of 3 numbers"},
      {"fiducials:\n  positions_mm: [[1, 2, 3]]\n  insert: maybe\n", "true or false"},
      {"sim:\n  photons_per_pixel: 0\n", "must be positive"},
      {"sim:\n  dose: 3\n", "unknown key 'dose'"},
  };
  for (const auto& [tail, message] : bad) {
    auto s2 = parse_scene(std::string(kValidScene) + tail, "reg.yaml", "/");
    ASSERT_FALSE(s2.ok()) << tail;
    EXPECT_EQ(s2.status().message().rfind("reg.yaml:", 0), 0u) << s2.status().message();
    EXPECT_NE(s2.status().message().find(message), std::string::npos) << s2.status().message();
  }
}

TEST(Scene, DuplicateDetectorNames) {
  std::string text = kValidScene;
  const std::string detector = text.substr(text.find("  - name: A"));
  text += detector;
  auto scene = parse_scene(text, "dup.yaml", "/");
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("duplicate detector name 'A'"), std::string::npos);
}

TEST(Scene, BothGeometryFormsIsAnError) {
  std::string text = kValidScene;
  text += "    source_mm: [0, -1000, 0]\n";
  auto scene = parse_scene(text, "both.yaml", "/");
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("use one"), std::string::npos);
}

TEST(Scene, OddYamlShapesAreErrorsNotCrashes) {
  for (const char* text :
       {"[1, 2, 3]", "version: 1\n? [a, b]\n: c\n", "version: {a: 1}\n", "42", "version: 1\nct: [1]\n",
        "version: 1\nct: {path: x}\nroi: {centre_mm: [0,0,0]}\ndetectors: 3\n"}) {
    auto scene = parse_scene(text, "odd.yaml", "/");
    EXPECT_FALSE(scene.ok()) << text;
    EXPECT_EQ(scene.status().message().rfind("odd.yaml", 0), 0u) << scene.status().message();
  }
}

TEST(Scene, EmptyAndMissingFiles) {
  auto empty = parse_scene("", "empty.yaml", "/");
  ASSERT_FALSE(empty.ok());
  EXPECT_NE(empty.status().message().find("empty"), std::string::npos);
  auto missing = load_scene("/nonexistent/scene.yaml");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_FALSE(load_scene("builtin:knee").ok());
}

// Issue 50 probe: a scene path naming /dev/zero took memory without end, and a FIFO blocked for
// ever. A scene (and any YAML a person writes for lftrack) is a regular file of at most 1 MiB.
TEST(Scene, AFileThatIsNoSceneFileIsRefusedAtOnce) {
  test::TempDir dir;
  const auto fifo = dir.path() / "scene.yaml";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const auto big = dir.path() / "big.yaml";
  std::ofstream(big) << std::string((1 << 20) + 1, '#');
  for (const std::string& path : {std::string("/dev/zero"), fifo.string(), dir.path().string(), big.string()}) {
    auto scene = load_scene(path);
    ASSERT_FALSE(scene.ok()) << path;
    EXPECT_NE(scene.status().message().find(path), std::string::npos) << scene.status().message();
  }
  EXPECT_NE(load_scene(big.string()).status().message().find("1 MiB"), std::string::npos);
}

// Issue 50 probe: a detector named "../../escaped" wrote its light field two folders above
// --lf-dir. A name is what `calibrate detector --detector` takes.
TEST(Scene, ADetectorNameIsAFileNamePart) {
  for (const std::string& bad : std::vector<std::string>{"../../escaped", "a/b", ".hidden", "with space",
                                                          std::string(65, 'x'), "\xc3\xbc"}) {
    std::string text = kValidScene;
    const std::size_t at = text.find("  - name: A") + 10;
    text.replace(at, 1, "\"" + bad + "\"");
    auto scene = parse_scene(text, "names.yaml", "/");
    ASSERT_FALSE(scene.ok()) << bad;
    EXPECT_NE(scene.status().message().find("a detector name is 1 to 64"), std::string::npos)
        << scene.status().message();
  }
  std::string text = kValidScene;
  text.replace(text.find("  - name: A") + 10, 1, "lateral-left_2.0");
  EXPECT_TRUE(parse_scene(text, "names.yaml", "/").ok());
}

TEST(Scene, ShippedExampleScenesParse) {
  const auto dir = std::filesystem::path(LFTRACK_SOURCE_DIR) / "scenes";
  int count = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().extension() != ".yaml") continue;
    auto scene = load_scene(entry.path().string());
    EXPECT_TRUE(scene.ok()) << scene.status().message();
    ++count;
  }
  EXPECT_GE(count, 1);
}

// Every scene shipped in scenes/ (and scenes/room/, with its room files) parses and validates: a user copies them.
// scenes/commissioning/ holds the scenes' commissioning files, which read as such.
TEST(Scene, EveryShippedSceneFileLoads) {
  int count = 0;
  for (const auto& entry :
       std::filesystem::recursive_directory_iterator(std::filesystem::path(LFTRACK_SOURCE_DIR) / "scenes")) {
    if (entry.path().extension() != ".yaml") continue;
    if (entry.path().parent_path().filename() == "commissioning") {
      auto record = read_commissioning_file(entry.path());
      EXPECT_TRUE(record.ok()) << entry.path() << ": " << record.status().message();
      continue;
    }
    ++count;
    auto scene = load_scene(entry.path().string());
    if (!scene.ok() && scene.status().message().find("this looks like a room file") != std::string::npos) {
      // A room file (scenes/room/): it loads with a patient.
      scene = parse_scene("version: 1\nroom: " + entry.path().string() + "\nct: {path: builtin:phantom}\n",
                          "patient.yaml", entry.path().parent_path());
    }
    EXPECT_TRUE(scene.ok()) << entry.path() << ": " << scene.status().message();
  }
  EXPECT_GE(count, 10);
}

}  // namespace
}  // namespace lftrack::session
