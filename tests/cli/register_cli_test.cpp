// `lftrack register` and its verdict, as a user runs it: good frames are accepted (exit 0); blank,
// saturated, noise and A/B-swapped frames are rejected with the reason (exit 1, --json carries the
// verdict); a one-detector scene is refused unless it says `tracking.single_view: true`, and then
// the unobservable direction is reported.

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <random>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/session/detector_calibration_file.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "lftrack/tracking/image_io.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

namespace fs = std::filesystem;

// One folder for the suite: the scene (the built-in phantom with a coarse light field, built once
// in a few seconds), its light fields and a good pair of frames.
class RegisterCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = std::make_unique<test::TempDir>();
    const std::string scene = test::coarse_phantom_scene_text();
    std::ofstream(scene_file()) << scene;
    // The same scene with detector A only, with and without the key that allows it.
    std::string one = scene;
    const auto b = one.find("  - name: B");
    one.erase(b, one.find("envelope:") - b);
    std::ofstream(dir_->path() / "one.yaml") << one;
    const std::string tracking = "tracking:\n";
    one.replace(one.find(tracking), tracking.size(), "tracking:\n  single_view: true\n");
    std::ofstream(dir_->path() / "one-allowed.yaml") << one;
  }
  static void TearDownTestSuite() { dir_.reset(); }

  static fs::path scene_file() { return dir_->path() / "phantom.yaml"; }
  static fs::path frames_dir() { return dir_->path() / "frames"; }

  // Runs `lftrack -q register` on the suite's scene with `args`; the exit status and the output.
  static Status run_register(std::vector<std::string> args, std::string* out, const fs::path& scene = {}) {
    std::vector<std::string> argv = {LFTRACK_BIN_PATH,
                                     "-q",
                                     "register",
                                     "--scene",
                                     (scene.empty() ? scene_file() : scene).string(),
                                     "--lf-dir",
                                     (dir_->path() / "lf").string()};
    argv.insert(argv.end(), args.begin(), args.end());
    return run_process(argv, out);
  }

  // A good pair at a gold pose, saved once (the first caller builds the light fields).
  static void save_good_frames() {
    if (fs::exists(frames_dir() / "frame_B.tif")) return;
    std::string out;
    ASSERT_TRUE(run_register({"--sim", "--gold", "2,-1,1.5,1,0.5,-1", "--seed", "3", "--save-frames",
                              frames_dir().string()},
                             &out)
                    .ok())
        << out;
  }

  // Frame `view` of the good pair with every pixel replaced by `pixel(row, col)`.
  template <class F>
  static fs::path edited_frame(const std::string& view, const std::string& name, F pixel) {
    auto frame = tracking::read_tiff(frames_dir() / ("frame_" + view + ".tif"));
    EXPECT_TRUE(frame.ok());
    for (int r = 0; r < frame->rows(); ++r)
      for (int c = 0; c < frame->cols(); ++c) frame->at(r, c) = pixel(r, c);
    tracking::ImageWriteOptions options;
    options.window = {0, 65535};
    const fs::path file = dir_->path() / (name + "_" + view + ".tif");
    EXPECT_TRUE(tracking::write_image(file, frame->view(), options).ok());
    return file;
  }

  // Registers the pair; expects a rejection (exit 1) and returns the --json verdict.
  static nlohmann::json rejected(const fs::path& a, const fs::path& b, std::vector<std::string> extra = {}) {
    std::vector<std::string> args = {"--frames", a.string(), b.string(), "--json"};
    args.insert(args.end(), extra.begin(), extra.end());
    std::string out;
    const Status s = run_register(args, &out);
    EXPECT_FALSE(s.ok()) << "a rejected registration exits non-zero: " << out;
    EXPECT_NE(out.find("REJECTED"), std::string::npos) << out;
    const auto brace = out.find('{');
    if (brace == std::string::npos) {
      ADD_FAILURE() << "no JSON: " << out;
      return {};
    }
    auto j = nlohmann::json::parse(out.substr(brace, out.rfind('}') - brace + 1));
    EXPECT_FALSE(j["verdict"]["ok"].get<bool>()) << out;
    return j["verdict"];
  }

  static std::unique_ptr<test::TempDir> dir_;
};
std::unique_ptr<test::TempDir> RegisterCli::dir_;

TEST_F(RegisterCli, GoodSimulatedFramesAreAcceptedAndExitZero) {
  save_good_frames();
  std::string out;
  ASSERT_TRUE(run_register({"--sim", "--gold", "2,-1,1.5,1,0.5,-1", "--seed", "5", "--json"}, &out).ok()) << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  EXPECT_TRUE(j["verdict"]["ok"].get<bool>()) << out;
  EXPECT_EQ(j["verdict"]["reason"], "ok");
  EXPECT_LT(j["tre_mm"]["mean"].get<double>(), 1.0);
  for (const auto& view : j["views"]) EXPECT_GT(view["check_ncc"].get<double>(), 0.9) << out;

  // The saved frames from files, in text: the verdict line, exit 0.
  ASSERT_TRUE(run_register({"--frames", (frames_dir() / "frame_A.tif").string(),
                            (frames_dir() / "frame_B.tif").string()},
                           &out)
                  .ok())
      << out;
  EXPECT_NE(out.find("verdict: ACCEPTED"), std::string::npos) << out;
}

TEST_F(RegisterCli, AllZeroFramesAreRejectedByTheImageQualityGate) {
  save_good_frames();
  const auto a = edited_frame("A", "zeros", [](int, int) { return 0.0f; });
  const auto b = edited_frame("B", "zeros", [](int, int) { return 0.0f; });
  const auto v = rejected(a, b);
  EXPECT_EQ(v["reason"], "image quality");
  EXPECT_EQ(v["view"], "A");
  EXPECT_EQ(v["image_quality"], "blank");
}

TEST_F(RegisterCli, SaturatedFramesAreRejectedByTheImageQualityGate) {
  save_good_frames();
  const auto a = (frames_dir() / "frame_A.tif");
  const auto b = edited_frame("B", "saturated", [](int, int) { return 4095.0f; });
  const auto v = rejected(a, b);
  EXPECT_EQ(v["reason"], "image quality");
  EXPECT_EQ(v["view"], "B");
  EXPECT_EQ(v["image_quality"], "saturated");

  std::string out;  // in text too, with the reason, exit 1
  EXPECT_FALSE(run_register({"--frames", a.string(), b.string()}, &out).ok());
  EXPECT_NE(out.find("verdict: REJECTED — image quality (view B: saturated frame)"), std::string::npos) << out;
}

TEST_F(RegisterCli, UniformNoiseFramesAreRejectedForLowSimilarity) {
  save_good_frames();
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> counts(0, 4095);
  const auto noise = [&](int, int) { return static_cast<float>(counts(rng)); };
  const auto a = edited_frame("A", "noise", noise);
  const auto b = edited_frame("B", "noise", noise);
  const auto v = rejected(a, b);
  EXPECT_EQ(v["reason"], "similarity below what the scene expects") << v.dump();
  EXPECT_LT(v["value"].get<double>(), v["limit"].get<double>());
}

TEST_F(RegisterCli, SwappedFramesAreRejectedWhateverTheMeasure) {
  save_good_frames();
  // The simulator exposes only each view's ROI window (and a margin), so a swapped frame would
  // fail the image-quality gate for its unexposed pixels. A real detector is exposed everywhere:
  // fill the unexposed pixels with the median exposed count, so that the frames reach the
  // registration and the verdict must tell them apart on their content.
  const auto exposed = [](const std::string& view, const std::string& name) {
    auto frame = tracking::read_tiff(frames_dir() / ("frame_" + view + ".tif"));
    EXPECT_TRUE(frame.ok());
    std::vector<float> counts;
    for (float v : frame->pixels())
      if (v > 0) counts.push_back(v);
    std::nth_element(counts.begin(), counts.begin() + static_cast<std::ptrdiff_t>(counts.size() / 2), counts.end());
    const float median = counts[counts.size() / 2];
    return edited_frame(view, name, [&](int r, int c) { return frame->at(r, c) > 0 ? frame->at(r, c) : median; });
  };
  const auto a = exposed("A", "exposed"), b = exposed("B", "exposed");
  std::string out;
  ASSERT_TRUE(run_register({"--frames", a.string(), b.string()}, &out).ok()) << "in order they are accepted: " << out;
  // mi (which scores these swapped frames 0.60, above its floor), and gc and pi, whose scores of
  // a mirrored spine overlap good ones: each frame's NCC against the DRR at the result rejects.
  for (const char* measure : {"mi", "gc", "pi"}) {
    const auto v = rejected(b, a, {"--similarity", measure});
    EXPECT_EQ(v["reason"], "similarity below what the scene expects") << measure << ": " << v.dump();
    EXPECT_EQ(v["units"], "ncc") << measure << ": " << v.dump();
  }
}

// The scene's detector calibration corrects --frames as it corrects the loop's frames (register
// used the simulator's model whatever the scene named): a flat calibration is accepted as the
// model is, one whose dark level lies above every count leaves nothing to register, and one that
// does not load is refused with the detector named.
TEST_F(RegisterCli, TheScenesDetectorCalibrationCorrectsTheFrames) {
  save_good_frames();
  auto frame = tracking::read_tiff(frames_dir() / "frame_A.tif");
  ASSERT_TRUE(frame.ok());
  const float brightest = *std::max_element(frame->pixels().begin(), frame->pixels().end());
  const auto write_calibration = [&](const std::string& name, float offset_counts) {
    calib::DetectorCalibration c;
    c.detector = "A";
    c.rows = frame->rows();
    c.cols = frame->cols();
    c.dark_frames = c.flood_frames = 8;
    c.offset_counts = tracking::Image<float>(c.rows, c.cols, offset_counts);
    c.noise_counts = tracking::Image<float>(c.rows, c.cols, 1.f);
    c.gain = tracking::Image<float>(c.rows, c.cols, 1.f);
    c.defective = tracking::Image<unsigned char>(c.rows, c.cols, 0);
    c.open_field_counts = 2.0 * brightest;
    c.saturation_counts = 4095;
    c.saturation_source = "bits";
    c.content_hash = calib::detector_calibration_hash(c);
    const fs::path file = dir_->path() / (name + ".tif");
    EXPECT_TRUE(write_detector_calibration(file, c, true).ok());
    return file;
  };
  const auto scene_with = [&](const std::string& name, const fs::path& calibration) {
    std::ifstream in(scene_file());
    std::string text((std::istreambuf_iterator<char>(in)), {});
    const auto line_end = text.find('\n', text.find("  - name: A"));
    text.insert(line_end + 1, "    calibration: " + calibration.string() + "\n");
    const fs::path scene = dir_->path() / (name + ".yaml");
    std::ofstream(scene) << text;
    return scene;
  };
  const std::vector<std::string> good = {"--frames", (frames_dir() / "frame_A.tif").string(),
                                         (frames_dir() / "frame_B.tif").string()};
  std::string out;
  EXPECT_TRUE(run_register(good, &out, scene_with("flat", write_calibration("flat", 0.f))).ok()) << out;
  EXPECT_NE(out.find("verdict: ACCEPTED"), std::string::npos) << out;

  EXPECT_FALSE(run_register(good, &out, scene_with("dark", write_calibration("dark", 2.f * brightest))).ok())
      << "every pixel at or below its dark level: " << out;
  EXPECT_EQ(out.find("verdict: ACCEPTED"), std::string::npos) << out;

  const fs::path broken = write_calibration("broken", 0.f);
  fs::resize_file(broken, fs::file_size(broken) / 2);
  EXPECT_FALSE(run_register(good, &out, scene_with("broken", broken)).ok()) << out;
  EXPECT_NE(out.find("detector A"), std::string::npos) << out;
  EXPECT_EQ(out.find("verdict"), std::string::npos) << "refused before registering: " << out;
}

TEST_F(RegisterCli, OneDetectorIsRefusedUnlessTheSceneSaysSoAndThenTheBlindDirectionIsReported) {
  std::string out;
  EXPECT_FALSE(run_register({"--sim", "--json"}, &out, dir_->path() / "one.yaml").ok()) << out;
  EXPECT_NE(out.find("a single view cannot see depth"), std::string::npos) << out;
  EXPECT_NE(out.find("single_view: true"), std::string::npos) << out;

  ASSERT_TRUE(run_register({"--sim", "--gold", "1,0,0,0,0,0", "--json"}, &out, dir_->path() / "one-allowed.yaml").ok())
      << out;
  const auto j = nlohmann::json::parse(out.substr(out.find('{')));
  ASSERT_TRUE(j.contains("unobservable_direction_room")) << out;
  const auto d = j["unobservable_direction_room"];
  EXPECT_NEAR(d[0].get<double>(), -M_SQRT1_2, 1e-6);
  EXPECT_NEAR(d[1].get<double>(), M_SQRT1_2, 1e-6);
  EXPECT_NEAR(d[2].get<double>(), 0.0, 1e-6);
  ASSERT_TRUE(run_register({"--sim", "--gold", "1,0,0,0,0,0"}, &out, dir_->path() / "one-allowed.yaml").ok())
      << out;
  EXPECT_NE(out.find("single view: depth along (-0.707, 0.707, 0.000) (room frame) is unobservable"),
            std::string::npos)
      << out;
}

}  // namespace
}  // namespace lftrack::session
