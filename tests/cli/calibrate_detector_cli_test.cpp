// `lftrack calibrate detector` as a user runs it: a calibration from folders of dark and flood
// frames, and every wrong input refused with exit 1, the reason, and nothing written.

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "lftrack/drivers/frame_files.hpp"
#include "lftrack/host/detector_calibration_file.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "test_data.hpp"

namespace lftrack::host {
namespace {

namespace fs = std::filesystem;

// `count` frames of a 40 x 32 detector: offset 200, dark noise 4, `signal` counts of flood; a
// hot pixel at (3, 4).
void write_frames(const fs::path& dir, int count, double signal, int rows = 32, int cols = 40) {
  fs::create_directories(dir);
  std::mt19937 rng(11);
  std::normal_distribution<double> unit(0, 1);
  for (int i = 0; i < count; ++i) {
    tracking::Image<std::uint16_t> f(rows, cols);
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) {
        const double v = (r == 3 && c == 4 ? 3000 : 200) + signal + 4 * unit(rng) + std::sqrt(signal) * unit(rng);
        f.at(r, c) = std::uint16_t(std::lround(std::max(0.0, v)));
      }
    char name[32];
    std::snprintf(name, sizeof name, "frame-%03d.tif", i);
    ASSERT_TRUE(drivers::write_frame_file((dir / name).c_str(), f.view()).ok());
  }
}

struct CliRun {
  bool ok;
  std::string out;
};
CliRun lftrack(const std::vector<std::string>& args) {
  std::vector<std::string> argv = {LFTRACK_BIN_PATH, "calibrate", "detector"};
  argv.insert(argv.end(), args.begin(), args.end());
  CliRun r;
  r.ok = run_process(argv, &r.out).ok();
  return r;
}

TEST(CalibrateDetectorCli, WritesTheCalibrationAndNeverOverwritesIt) {
  test::TempDir dir;
  write_frames(dir.path() / "dark", 10, 0);
  write_frames(dir.path() / "flood", 10, 1500);
  std::ofstream(dir.path() / "flood" / "notes.txt") << "taken at 80 kV";
  const std::string out = (dir.path() / "detector-A.tif").string();
  const std::vector<std::string> args = {"--dark", (dir.path() / "dark").string(), "--flood",
                                         (dir.path() / "flood").string(), "--out", out, "--detector", "A", "--bits",
                                         "12", "--json"};
  CliRun r = lftrack(args);
  ASSERT_TRUE(r.ok) << r.out;
  const auto j = nlohmann::json::parse(r.out.substr(r.out.find('{')));
  EXPECT_EQ(j["rows"].get<int>(), 32);
  EXPECT_EQ(j["cols"].get<int>(), 40);
  EXPECT_EQ(j["dark_frames"].get<int>(), 10);
  EXPECT_NEAR(j["open_field_counts"].get<double>(), 1500, 30);
  EXPECT_EQ(j["saturation_counts"].get<int>(), 4095);
  EXPECT_EQ(j["defects_by_rule"]["dark"].get<int>(), 1) << "the hot pixel";
  EXPECT_NE(r.out.find("other entries ignored"), std::string::npos) << "the notes file is named as ignored";
  auto loaded = load_detector_calibration(out);
  ASSERT_TRUE(loaded.ok()) << loaded.status().message();
  EXPECT_EQ(loaded->detector, "A");
  EXPECT_EQ(loaded->defective.at(3, 4), 1);
  const auto written = fs::last_write_time(out);
  r = lftrack(args);  // a second run over the first one's output
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.out.find("exists; give --overwrite"), std::string::npos) << r.out;
  EXPECT_EQ(fs::last_write_time(out), written);
  std::vector<std::string> again = args;
  again.push_back("--overwrite");
  EXPECT_TRUE(lftrack(again).ok);
}

TEST(CalibrateDetectorCli, RefusesBadInputWithAReasonAndWritesNothing) {
  test::TempDir dir;
  write_frames(dir.path() / "dark", 10, 0);
  write_frames(dir.path() / "flood", 10, 1500);
  write_frames(dir.path() / "few", 3, 1500);
  write_frames(dir.path() / "wide", 10, 1500, 32, 48);
  write_frames(dir.path() / "bright", 10, 5000);
  fs::create_directories(dir.path() / "empty");
  const std::string out = (dir.path() / "cal.tif").string();
  const auto refused = [&](const std::string& dark, const std::string& flood, const std::string& why,
                           std::vector<std::string> extra = {}) {
    std::vector<std::string> args = {"--dark", dark, "--flood", flood, "--out", out, "--bits", "12"};
    args.insert(args.end(), extra.begin(), extra.end());
    const CliRun r = lftrack(args);
    EXPECT_FALSE(r.ok) << why;
    EXPECT_NE(r.out.find(why), std::string::npos) << r.out;
    EXPECT_FALSE(fs::exists(out)) << "nothing written: " << why;
  };
  const std::string d = (dir.path() / "dark").string(), f = (dir.path() / "flood").string();
  refused((dir.path() / "nowhere").string(), f, "no such directory");
  refused((dir.path() / "empty").string(), f, "holds no frames");
  refused(d, (dir.path() / "few").string(), "too few flood frames: 3");
  refused(d, (dir.path() / "wide").string(), "the frame is 48 x 32 pixels");
  refused(f, d, "no brighter than the dark");
  refused(d, (dir.path() / "bright").string(), "the flood saturates");
  const CliRun to_folder = lftrack({"--dark", d, "--flood", f, "--out", dir.path().string()});
  EXPECT_FALSE(to_folder.ok);
  EXPECT_NE(to_folder.out.find("is a directory"), std::string::npos) << to_folder.out;
  refused(d, f, "robust SDs", {"--dark-sd", "nan"});
  refused(d, f, "robust SDs", {"--dark-sd", "-1"});
  // A frame file whose header claims a huge detector.
  fs::create_directories(dir.path() / "lying");
  std::ofstream(dir.path() / "lying" / "a.png") << "\x89PNG\r\n\x1a\n";
  refused((dir.path() / "lying").string(), f, "not a readable PNG");
}

}  // namespace
}  // namespace lftrack::host
