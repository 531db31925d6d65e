// `lftrack calibrate detector` as a user runs it: a calibration from folders of dark and flood
// frames (TIFF and PNG), the default output never replaced, and every wrong input refused with
// exit 1, the reason, and nothing written (option values out of range: Cli/UsageError).

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <random>

#include "cli_text.hpp"
#include "lftrack/drivers/frame_files.hpp"
#include "lftrack/session/detector_calibration_file.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

using test::quoted;
using test::CliRun;
using test::contents;

namespace fs = std::filesystem;

// `count` frames of a 40 x 32 detector: offset 200, dark noise 4, `signal` counts of flood
// (clipped at `clip`); a hot pixel at (3, 4). Named frame-000.EXT ...
void write_frames(const fs::path& dir, int count, double signal, int rows = 32, int cols = 40,
                  const std::string& ext = ".tif", int clip = 65535, unsigned seed = 11) {
  fs::create_directories(dir);
  std::mt19937 rng(seed);
  std::normal_distribution<double> unit(0, 1);
  for (int i = 0; i < count; ++i) {
    tracking::Image<std::uint16_t> f(rows, cols);
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) {
        const double v = (r == 3 && c == 4 ? 1500 : 200) + signal + 4 * unit(rng) + std::sqrt(signal) * unit(rng);
        f.at(r, c) = std::uint16_t(std::clamp(std::lround(v), 0L, long(clip)));
      }
    char name[32];
    std::snprintf(name, sizeof name, "frame-%03d%s", i, ext.c_str());
    ASSERT_TRUE(drivers::write_frame_file((dir / name).c_str(), f.view()).ok());
  }
}

// An 8-bit greyscale PNG, written by hand (stored deflate blocks), as a camera tool might save.
void write_8bit_png(const fs::path& path, int rows, int cols) {
  const auto crc32 = [](const std::string& bytes) {
    std::uint32_t crc = 0xffffffffu;
    for (unsigned char b : bytes) {
      crc ^= b;
      for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xedb88320u & (0u - (crc & 1u)));
    }
    return crc ^ 0xffffffffu;
  };
  const auto be32 = [](std::uint32_t v) {
    return std::string{char(v >> 24), char(v >> 16), char(v >> 8), char(v)};
  };
  const auto chunk = [&](const std::string& type, const std::string& data) {
    return be32(std::uint32_t(data.size())) + type + data + be32(crc32(type + data));
  };
  std::string raw;  // filter byte 0, then the row
  for (int r = 0; r < rows; ++r) raw += std::string(1, '\0') + std::string(std::size_t(cols), char(100));
  std::uint32_t a = 1, b = 0;
  for (unsigned char c : raw) {
    a = (a + c) % 65521;
    b = (b + a) % 65521;
  }
  ASSERT_LT(raw.size(), 65535u);
  const auto n = std::uint16_t(raw.size());
  std::string zlib = {char(0x78), char(0x01), char(0x01), char(n & 0xff), char(n >> 8), char(~n & 0xff),
                      char((~n >> 8) & 0xff)};
  zlib += raw + be32((b << 16) | a);
  const std::string ihdr = be32(std::uint32_t(cols)) + be32(std::uint32_t(rows)) + std::string{8, 0, 0, 0, 0};
  std::ofstream(path, std::ios::binary) << "\x89PNG\r\n\x1a\n" + chunk("IHDR", ihdr) + chunk("IDAT", zlib) +
                                               chunk("IEND", "");
}

// `lftrack calibrate detector ARGS` in `cwd`, its exit code and output.
CliRun calibrate_detector(const std::vector<std::string>& args, const fs::path& cwd, const fs::path& log_dir) {
  std::string command = "cd ";
  command += quoted(cwd.string());
  command += " && ";
  command += quoted(LFTRACK_BIN_PATH);
  command += " calibrate detector";
  for (const auto& a : args) {
    command += ' ';
    command += quoted(a);
  }
  const fs::path log = log_dir / "cli-output.txt";
  command += " >";
  command += quoted(log.string());
  command += " 2>&1";
  CliRun r;
  const int status = std::system(command.c_str());
  if (status != -1 && WIFEXITED(status)) r.exit_code = WEXITSTATUS(status);
  std::ifstream in(log);
  r.out.assign(std::istreambuf_iterator<char>(in), {});
  return r;
}

TEST(CalibrateDetectorCli, WritesTheCalibrationAndNeverOverwritesIt) {
  test::TempDir dir;
  write_frames(dir.path() / "dark", 10, 0);
  write_frames(dir.path() / "flood", 10, 1500, 32, 40, ".png");
  const fs::path out = dir.path() / "cal" / "detector-A.tif";
  const std::vector<std::string> args = {"--dark", (dir.path() / "dark").string(), "--flood",
                                         (dir.path() / "flood").string(), "--out", out.string(), "--detector", "A",
                                         "--bits", "12", "--json"};
  CliRun r = calibrate_detector(args, dir.path(), dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const auto j = nlohmann::json::parse(r.out.substr(r.out.find('{')));
  EXPECT_EQ(j["file"], out.string());
  EXPECT_EQ(j["detector"], "A");
  EXPECT_EQ(j["rows"].get<int>(), 32);
  EXPECT_EQ(j["cols"].get<int>(), 40);
  EXPECT_EQ(j["dark_frames"].get<int>(), 10);
  EXPECT_EQ(j["flood_frames"].get<int>(), 10);
  EXPECT_NEAR(j["offset_median_counts"].get<double>(), 200, 2);
  EXPECT_NEAR(j["noise_median_counts"].get<double>(), 4, 0.6);
  EXPECT_NEAR(j["open_field_counts"].get<double>(), 1500, 30);
  EXPECT_EQ(j["saturation_counts"].get<int>(), 4095);
  EXPECT_EQ(j["saturation_source"], "bits");
  EXPECT_EQ(j["defects_by_rule"]["dark"].get<int>(), 1) << "the hot pixel";
  EXPECT_EQ(j["defects"].get<int>(), 1);
  EXPECT_NE(j["defect_rule"].get<std::string>().find("robust SDs"), std::string::npos);
  auto loaded = load_detector_calibration(out);
  ASSERT_TRUE(loaded.ok()) << loaded.status().message();
  EXPECT_EQ(loaded->detector, "A");
  EXPECT_EQ(loaded->defective.at(3, 4), 1);
  EXPECT_EQ(loaded->content_hash, j["content_hash"]);
  // A second run over the first one's output: refused, the file untouched.
  const std::string first = contents(out);
  r = calibrate_detector(args, dir.path(), dir.path());
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("exists; give --overwrite"), std::string::npos) << r.out;
  EXPECT_EQ(contents(out), first);
  std::vector<std::string> again = args;
  again.push_back("--overwrite");
  r = calibrate_detector(again, dir.path(), dir.path());
  EXPECT_EQ(r.exit_code, 0) << r.out;
  EXPECT_TRUE(load_detector_calibration(out).ok());
  // The text summary.
  again.erase(std::find(again.begin(), again.end(), "--json"));
  r = calibrate_detector(again, dir.path(), dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.out;
  for (const char* line : {"detector A: 40 x 32 pixels from 10 dark and 10 flood frames", "offset median ",
                           "temporal noise median", "counts (flood - dark, median over good pixels)", "saturation 4095 counts (2^12 - 1, from --bits)",
                           "defective pixels masked: 1", "dark 1, noise 0, gain 0, saturated 0, line 0",
                           "rule: a pixel is defective if", "written: "})
    EXPECT_NE(r.out.find(line), std::string::npos) << "missing '" << line << "' in:\n" << r.out;
}

TEST(CalibrateDetectorCli, DefaultOutputIsNamedAfterTheDetectorAndNeverReplaced) {
  test::TempDir dir;
  write_frames(dir.path() / "dark", 8, 0);
  write_frames(dir.path() / "flood", 8, 1500);
  const fs::path room = dir.path() / "room";
  fs::create_directories(room);
  const std::vector<std::string> args = {"--dark", (dir.path() / "dark").string(), "--flood",
                                         (dir.path() / "flood").string(), "--detector", "B"};
  CliRun r = calibrate_detector(args, room, dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.out;
  const fs::path file = room / "out" / "calibration" / "detector-B.tif";
  ASSERT_TRUE(fs::exists(file)) << r.out;
  EXPECT_NE(r.out.find("written: out/calibration/detector-B.tif"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("saturation 4095 counts (inferred"), std::string::npos) << r.out;
  const std::string first = contents(file);
  r = calibrate_detector(args, room, dir.path());
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("out/calibration/detector-B.tif exists; give --overwrite"), std::string::npos) << r.out;
  EXPECT_EQ(contents(file), first);
  r = calibrate_detector({"--dark", (dir.path() / "dark").string(), "--flood", (dir.path() / "flood").string()}, room,
                         dir.path());
  EXPECT_EQ(r.exit_code, 0) << r.out;
  EXPECT_TRUE(fs::exists(room / "out" / "calibration" / "detector-detector.tif")) << r.out;
}

TEST(CalibrateDetectorCli, RefusesBadInputWithAReasonAndWritesNothing) {
  test::TempDir dir;
  const fs::path& d = dir.path();
  write_frames(d / "dark", 10, 0);
  write_frames(d / "flood", 10, 1500);
  write_frames(d / "one", 1, 0);
  write_frames(d / "few", 3, 1500);
  write_frames(d / "wide", 10, 1500, 32, 48);
  write_frames(d / "mixed", 9, 1500);
  write_frames(d / "mixed-odd", 1, 1500, 33, 40, ".tif", 65535, 3);
  fs::copy_file(d / "mixed-odd" / "frame-000.tif", d / "mixed" / "frame-999.tif");
  write_frames(d / "saturated", 10, 5000, 32, 40, ".tif", 4095);  // a 12-bit detector clipped
  write_frames(d / "white", 10, 70000);                            // 16-bit full scale everywhere
  write_frames(d / "notes", 10, 1500);
  std::ofstream(d / "notes" / "notes.txt") << "taken at 80 kV";
  write_frames(d / "nested", 10, 1500);
  fs::create_directories(d / "nested" / "old");
  fs::create_directories(d / "eight-bit");
  for (int i = 0; i < 10; ++i) write_8bit_png(d / "eight-bit" / ("frame-" + std::to_string(i) + ".png"), 32, 40);
  fs::create_directories(d / "empty");
  write_frames(d / "lying", 9, 0);
  std::ofstream(d / "lying" / "frame-lie.png") << "\x89PNG\r\n\x1a\n";  // a header and nothing else
  std::ofstream(d / "a-file") << "not a folder";
  const fs::path outdir = d / "out";
  fs::create_directories(outdir);
  const std::string out = (outdir / "cal.tif").string();
  const auto nothing_written = [&](const std::string& why) {
    EXPECT_TRUE(fs::is_empty(outdir)) << "nothing written: " << why;
    for (const auto& e : fs::directory_iterator(outdir)) ADD_FAILURE() << "left behind: " << e.path();
  };
  const auto refused = [&](const fs::path& dark, const fs::path& flood, const std::string& why,
                           std::vector<std::string> extra = {}) {
    std::vector<std::string> args = {"--dark", dark.string(), "--flood", flood.string(), "--out", out};
    args.insert(args.end(), extra.begin(), extra.end());
    const CliRun r = calibrate_detector(args, d, d);
    EXPECT_EQ(r.exit_code, 1) << why << ":\n" << r.out;
    EXPECT_NE(r.out.find(why), std::string::npos) << r.out;
    nothing_written(why);
  };
  refused(d / "nowhere", d / "flood", "dark folder " + (d / "nowhere").string() + ": no such directory");
  refused(d / "a-file", d / "flood", "is not a directory");
  refused(d / "empty", d / "flood", "dark folder " + (d / "empty").string() + " holds no frames");
  refused(d / "one", d / "flood", "too few frames: 1 dark in");
  refused(d / "dark", d / "few", "too few frames: 10 dark in " + (d / "dark").string() + ", 3 flood in");
  refused(d / "dark", d / "wide", "flood frame " + (d / "wide" / "frame-000.tif").string() +
                                      " is 48 x 32 pixels; " + (d / "dark" / "frame-000.tif").string() + " is 40 x 32");
  refused(d / "mixed", d / "flood", "dark frame " + (d / "mixed" / "frame-999.tif").string() + " is 40 x 33 pixels");
  refused(d / "notes", d / "flood", "holds 1 entry that is not a frame file (.tif, .tiff, .png): notes.txt");
  refused(d / "dark", d / "nested", "not a frame file (.tif, .tiff, .png): old/");
  refused(d / "eight-bit", d / "flood", "a frame must be a 16-bit greyscale PNG");
  refused(d / "lying", d / "flood", (d / "lying" / "frame-lie.png").string() + ": not a readable PNG");
  refused(d / "flood", d / "dark", "the flood is no brighter than the dark");
  refused(d / "dark", d / "dark", "the flood is no brighter than the dark");
  refused(d / "dark", d / "saturated", "the flood saturates: 100.00 % of its pixel values are at or above 4095");
  refused(d / "dark", d / "saturated", "at or above 4095 counts (saturation from --bits", {"--bits", "12"});
  refused(d / "dark", d / "white", "the flood saturates: 100.00 % of its pixel values are at or above 65535");
  // (Option values out of range are usage errors, exit 2: Cli/UsageError.)
  refused(d / "dark", d / "flood", "a detector name is 1 to 64 letters", {"--detector", "../../etc"});
  // --out: a folder, a path ending in '/', an existing file.
  for (const std::string& folder : {outdir.string(), outdir.string() + "/", (outdir / "new").string() + "/"}) {
    const CliRun r = calibrate_detector({"--dark", (d / "dark").string(), "--flood", (d / "flood").string(), "--out",
                                         folder}, d, d);
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_NE(r.out.find("; name the calibration file"), std::string::npos) << r.out;
    nothing_written(folder);
  }
  const fs::path notes = d / "notes.tif";
  std::ofstream(notes) << "someone's file";
  const CliRun r = calibrate_detector({"--dark", (d / "dark").string(), "--flood", (d / "flood").string(), "--out",
                                       notes.string()}, d, d);
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.out.find("notes.tif exists; give --overwrite"), std::string::npos) << r.out;
  EXPECT_EQ(contents(notes), "someone's file");
  // --overwrite replaces only an earlier calibration: not someone's file, not one of the frames.
  std::vector<fs::path> dark_frames(fs::directory_iterator(d / "dark"), fs::directory_iterator{});
  ASSERT_FALSE(dark_frames.empty());
  const fs::path first_dark = dark_frames.front();
  for (const fs::path& other : {notes, first_dark}) {
    const std::string before = contents(other);
    const CliRun o = calibrate_detector({"--dark", (d / "dark").string(), "--flood", (d / "flood").string(), "--out",
                                         other.string(), "--overwrite"}, d, d);
    EXPECT_EQ(o.exit_code, 1) << o.out;
    EXPECT_NE(o.out.find("is not a detector calibration"), std::string::npos) << o.out;
    EXPECT_EQ(contents(other), before) << other;
  }
  // After all that, the good folders do calibrate.
  const CliRun ok = calibrate_detector({"--dark", (d / "dark").string(), "--flood", (d / "flood").string(), "--out",
                                        out}, d, d);
  EXPECT_EQ(ok.exit_code, 0) << ok.out;
  EXPECT_TRUE(load_detector_calibration(out).ok());
}

// Issue 50: eight copies of one dark frame and one flood frame (temporal noise 0.00), and 1 x 1
// frames, were calibrated. The copies are named by their files.
TEST(CalibrateDetectorCli, RefusesCopiedFramesAndFramesTooSmall) {
  test::TempDir dir;
  const fs::path& d = dir.path();
  write_frames(d / "dark", 8, 0);
  write_frames(d / "flood", 8, 1500);
  write_frames(d / "frozen", 1, 0);
  for (int i = 1; i < 8; ++i)
    fs::copy_file(d / "frozen" / "frame-000.tif", d / "frozen" / ("frame-00" + std::to_string(i) + ".tif"));
  write_frames(d / "copied", 8, 1500);
  fs::copy_file(d / "copied" / "frame-002.tif", d / "copied" / "frame-006.tif", fs::copy_options::overwrite_existing);
  write_frames(d / "tiny-dark", 8, 0, 1, 1);
  write_frames(d / "tiny-flood", 8, 1500, 1, 1);
  const fs::path out = d / "out" / "cal.tif";
  const auto refused = [&](const fs::path& dark, const fs::path& flood, const std::string& why) {
    const CliRun r = calibrate_detector({"--dark", dark.string(), "--flood", flood.string(), "--out", out.string()}, d, d);
    EXPECT_EQ(r.exit_code, 1) << why << ":\n" << r.out;
    EXPECT_NE(r.out.find(why), std::string::npos) << r.out;
    EXPECT_FALSE(fs::exists(out)) << why;
  };
  refused(d / "frozen", d / "flood",
          "dark frames " + (d / "frozen" / "frame-000.tif").string() + " and " +
              (d / "frozen" / "frame-001.tif").string() + " are identical pixel for pixel");
  refused(d / "dark", d / "copied",
          "flood frames " + (d / "copied" / "frame-002.tif").string() + " and " +
              (d / "copied" / "frame-006.tif").string() + " are identical");
  refused(d / "tiny-dark", d / "tiny-flood", "the frames are 1 x 1 pixels; a calibration needs at least 8 x 8");
}

}  // namespace
}  // namespace lftrack::session
