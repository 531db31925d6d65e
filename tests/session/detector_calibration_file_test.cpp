// The detector calibration file (host/detector_calibration_file.hpp): what is written is read
// back whole; a damaged, truncated, edited or lying file is refused with the reason; nothing is
// overwritten without being asked.

#include "lftrack/host/detector_calibration_file.hpp"

#include <gtest/gtest.h>
#include <tiffio.h>

#include <fstream>
#include <nlohmann/json.hpp>

#include "test_data.hpp"

namespace lftrack::host {
namespace {

calib::DetectorCalibration small_calibration() {
  calib::DetectorCalibration c;
  c.detector = "A";
  c.rows = 6;
  c.cols = 5;
  c.dark_frames = c.flood_frames = 8;
  c.offset_counts = tracking::Image<float>(6, 5, 100.f);
  c.noise_counts = tracking::Image<float>(6, 5, 3.f);
  c.gain = tracking::Image<float>(6, 5, 1.f);
  c.defective = tracking::Image<unsigned char>(6, 5, 0);
  c.gain.at(2, 3) = 1.25f;
  c.offset_counts.at(1, 1) = 4000.f;
  c.defective.at(1, 1) = 1;
  c.defects = 1;
  c.defects_by_rule[calib::kDefectDark] = 1;
  c.open_field_counts = 2000;
  c.saturation_counts = 4095;
  c.content_hash = calib::detector_calibration_hash(c);
  return c;
}

void expect_refused(const std::filesystem::path& file, const std::string& why) {
  auto loaded = load_detector_calibration(file);
  ASSERT_FALSE(loaded.ok()) << file;
  EXPECT_NE(loaded.status().message().find(why), std::string::npos) << loaded.status().message();
}

TEST(DetectorCalibrationFile, RoundTrips) {
  test::TempDir dir;
  const auto file = dir.path() / "detector-A.tif";
  const calib::DetectorCalibration c = small_calibration();
  ASSERT_TRUE(write_detector_calibration(file, c, false).ok());
  auto back = load_detector_calibration(file);
  ASSERT_TRUE(back.ok()) << back.status().message();
  EXPECT_EQ(back->detector, "A");
  EXPECT_EQ(back->rows, 6);
  EXPECT_EQ(back->cols, 5);
  EXPECT_EQ(back->gain.at(2, 3), 1.25f);
  EXPECT_EQ(back->offset_counts.at(1, 1), 4000.f);
  EXPECT_EQ(back->defective.at(1, 1), 1);
  EXPECT_EQ(back->defective.at(0, 0), 0);
  EXPECT_EQ(back->open_field_counts, 2000);
  EXPECT_EQ(back->saturation_counts, 4095);
  EXPECT_EQ(back->defects_by_rule[calib::kDefectDark], 1);
  EXPECT_EQ(back->content_hash, c.content_hash);
}

TEST(DetectorCalibrationFile, NeverOverwritesUnasked) {
  test::TempDir dir;
  const auto file = dir.path() / "detector-A.tif";
  std::ofstream(file) << "someone's notes";
  const auto refused = write_detector_calibration(file, small_calibration(), false);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.message().find("--overwrite"), std::string::npos);
  std::ifstream in(file);
  std::string kept;
  std::getline(in, kept);
  EXPECT_EQ(kept, "someone's notes");
  EXPECT_TRUE(write_detector_calibration(file, small_calibration(), true).ok());
  EXPECT_TRUE(load_detector_calibration(file).ok());
  std::filesystem::create_symlink(dir.path() / "elsewhere", dir.path() / "link.tif");
  EXPECT_FALSE(write_detector_calibration(dir.path() / "link.tif", small_calibration(), true).ok())
      << "never through a link";
  for (const auto& e : std::filesystem::directory_iterator(dir.path()))
    EXPECT_EQ(e.path().string().find(".partial-"), std::string::npos) << "no temporary left: " << e.path();
}

TEST(DetectorCalibrationFile, RefusesDamagedOrLyingFiles) {
  test::TempDir dir;
  const auto good = dir.path() / "good.tif";
  ASSERT_TRUE(write_detector_calibration(good, small_calibration(), false).ok());
  expect_refused(dir.path() / "absent.tif", "no such detector calibration file");
  std::ofstream(dir.path() / "text.tif") << "not an image";
  expect_refused(dir.path() / "text.tif", "not a readable TIFF");
  // Edited maps: the hash no longer matches.
  calib::DetectorCalibration edited = small_calibration();
  edited.gain.at(0, 0) = 0.5f;  // the hash was made before
  ASSERT_TRUE(write_detector_calibration(dir.path() / "edited.tif", edited, false).ok());
  expect_refused(dir.path() / "edited.tif", "do not match their hash");
  // Truncated.
  const auto size = std::filesystem::file_size(good);
  std::filesystem::copy_file(good, dir.path() / "cut.tif");
  std::filesystem::resize_file(dir.path() / "cut.tif", size / 2);
  EXPECT_FALSE(load_detector_calibration(dir.path() / "cut.tif").ok());
  // A TIFF whose metadata claims a huge detector over tiny pages, or misses keys, or is
  // another version: refused before memory is given to it.
  const auto lying = [&](const std::string& name, const nlohmann::json& meta) {
    const auto path = dir.path() / name;
    TIFF* tif = TIFFOpen(path.c_str(), "w");
    float pixel = 1;
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, 1);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 1);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 32);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
    TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_IEEEFP);
    TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, meta.dump().c_str());
    TIFFWriteScanline(tif, &pixel, 0, 0);
    TIFFClose(tif);
    return path;
  };
  nlohmann::json meta = {{"format", "lftrack detector calibration"}, {"version", 1}, {"detector", "A"},
                         {"rows", 16000}, {"cols", 16000}, {"dark_frames", 8}, {"flood_frames", 8},
                         {"open_field_counts", 2000}, {"saturation_counts", 4095}, {"bits", 12},
                         {"defect_rule", {{"dark_sd", 6}, {"noise_sd", 6}, {"gain_low", 0.5}, {"gain_high", 1.5},
                                          {"line_low", 0.8}, {"line_high", 1.25}, {"max_saturated_fraction", 0.01},
                                          {"min_signal_counts", 50}}},
                         {"defects", {{"dark", 0}, {"noise", 0}, {"gain", 0}, {"saturated", 0}, {"line", 0}, {"masked", 0}}},
                         {"content_hash", "0"}};
  expect_refused(lying("huge.tif", meta), "cannot hold four 16000 x 16000 float maps");
  nlohmann::json missing = meta;
  missing.erase("open_field_counts");
  expect_refused(lying("missing.tif", missing), "metadata incomplete");
  nlohmann::json version = meta;
  version["version"] = 9;
  expect_refused(lying("version.tif", version), "version 9");
  nlohmann::json negative = meta;
  negative["rows"] = -3;
  expect_refused(lying("negative.tif", negative), "1 to 16384 a side");
  nlohmann::json one = meta;
  one["rows"] = one["cols"] = 1;
  expect_refused(lying("one-page.tif", one), "page 2 (gain) is missing");  // one page of four
}

}  // namespace
}  // namespace lftrack::host
