// The detector calibration file (host/detector_calibration_file.hpp): what is written is read
// back whole; a damaged, truncated, edited or lying file is refused with the reason and never
// crashes the loader; nothing is overwritten without being asked.

#include "lftrack/session/detector_calibration_file.hpp"

#include <gtest/gtest.h>
#include <tiffio.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "test_data.hpp"

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

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
  c.open_field_counts = 2000.125;
  c.saturation_counts = 4095;
  c.saturation_source = "bits";
  c.rule.bits = 12;
  c.rule.dark_sd = 7.5;
  c.offset_median_counts = 100;
  c.noise_median_counts = 3;
  c.content_hash = calib::detector_calibration_hash(c);
  return c;
}

std::string message_of(const fs::path& file) {
  auto loaded = load_detector_calibration(file);
  return loaded.ok() ? std::string("(loaded)") : loaded.status().message();
}

void expect_file_refused(const fs::path& file, const std::string& why) {
  const std::string message = message_of(file);
  EXPECT_NE(message.find(why), std::string::npos) << "expected '" << why << "', got: " << message;
}

// The metadata of a file written by write_detector_calibration.
json metadata_of(const fs::path& file) {
  TIFF* tif = TIFFOpen(file.c_str(), "r");
  EXPECT_NE(tif, nullptr);
  char* description = nullptr;
  TIFFGetField(tif, TIFFTAG_IMAGEDESCRIPTION, &description);
  json j = json::parse(description);
  TIFFClose(tif);
  return j;
}

// A hand-made calibration file: `pages` pages of rows x cols values of `bits`-bit float
// (`values[p]` when given, else 0), the description (if not empty) on the first.
struct RawFile {
  int pages = 4, rows = 6, cols = 5, bits = 32;
  std::vector<std::vector<float>> values;
  void write(const fs::path& path, const std::string& description) const {
    TIFF* tif = TIFFOpen(path.c_str(), "w");
    ASSERT_NE(tif, nullptr);
    for (int p = 0; p < pages; ++p) {
      TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, std::uint32_t(cols));
      TIFFSetField(tif, TIFFTAG_IMAGELENGTH, std::uint32_t(rows));
      TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, bits);
      TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
      TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_IEEEFP);
      TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, std::uint32_t(rows));
      if (p == 0 && !description.empty()) TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, description.c_str());
      std::vector<double> row(std::size_t(cols), 0.0);
      for (int r = 0; r < rows; ++r) {
        for (int k = 0; k < cols; ++k)
          row[std::size_t(k)] = std::size_t(p) < values.size() ? values[std::size_t(p)][std::size_t(r * cols + k)] : 0.0;
        if (bits == 32) {
          std::vector<float> f(row.begin(), row.end());
          TIFFWriteScanline(tif, f.data(), std::uint32_t(r), 0);
        } else {
          TIFFWriteScanline(tif, row.data(), std::uint32_t(r), 0);
        }
      }
      TIFFWriteDirectory(tif);
    }
    TIFFClose(tif);
  }
};

// The pages of `c` as RawFile values.
std::vector<std::vector<float>> pages_of(const calib::DetectorCalibration& c) {
  std::vector<float> defects(c.defective.pixels().begin(), c.defective.pixels().end());
  return {c.offset_counts.pixels(), c.gain.pixels(), c.noise_counts.pixels(), defects};
}

// Where page `page`'s pixel data starts in `file` (one strip per page, as written).
std::uint64_t page_data_offset(const fs::path& file, int page) {
  TIFF* tif = TIFFOpen(file.c_str(), "r");
  EXPECT_TRUE(TIFFSetDirectory(tif, tdir_t(page)));
  const std::uint64_t offset = TIFFGetStrileOffset(tif, 0);
  TIFFClose(tif);
  return offset;
}

void set_byte(const fs::path& file, std::uint64_t at, unsigned char value) {
  std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp(std::streamoff(at));
  f.put(char(value));
}

TEST(DetectorCalibrationFile, RoundTrips) {
  test::TempDir dir;
  const auto file = dir.path() / "detector-A.tif";
  calib::DetectorCalibration c = small_calibration();
  c.content_hash = "stale";  // the writer hashes what it writes
  ASSERT_TRUE(write_detector_calibration(file, c, false).ok());
  auto back = load_detector_calibration(file);
  ASSERT_TRUE(back.ok()) << back.status().message();
  EXPECT_EQ(back->detector, "A");
  EXPECT_EQ(back->rows, 6);
  EXPECT_EQ(back->cols, 5);
  EXPECT_EQ(back->dark_frames, 8);
  EXPECT_EQ(back->flood_frames, 8);
  EXPECT_EQ(back->offset_counts.pixels(), c.offset_counts.pixels());
  EXPECT_EQ(back->gain.pixels(), c.gain.pixels());
  EXPECT_EQ(back->noise_counts.pixels(), c.noise_counts.pixels());
  EXPECT_EQ(back->defective.pixels(), c.defective.pixels());
  EXPECT_EQ(back->open_field_counts, 2000.125);
  EXPECT_EQ(back->saturation_counts, 4095);
  EXPECT_EQ(back->saturation_source, "bits");
  EXPECT_EQ(back->offset_median_counts, 100);
  EXPECT_EQ(back->noise_median_counts, 3);
  EXPECT_EQ(back->defects, 1);
  EXPECT_EQ(back->defects_by_rule[calib::kDefectDark], 1);
  EXPECT_EQ(back->rule.bits, 12);
  EXPECT_EQ(back->rule.dark_sd, 7.5);
  EXPECT_EQ(back->content_hash, calib::detector_calibration_hash(small_calibration()));
  EXPECT_EQ(back->created.size(), 20u) << back->created;  // 2026-01-02T03:04:05Z
  const json meta = metadata_of(file);
  EXPECT_EQ(meta["format"], "lftrack detector calibration");
  EXPECT_EQ(meta["version"], kDetectorCalibrationVersion);
  EXPECT_EQ(meta["hash_algorithm"], "FNV-1a 64");
  EXPECT_NE(meta["defect_rule"]["text"].get<std::string>().find("7.5 robust SDs"), std::string::npos);
  EXPECT_EQ(meta["defects"]["masked"], 1);
  // The loop's correction from the file: the defect at gain 0.
  const tracking::DetectorCorrection corr = calib::to_detector_correction(*back);
  EXPECT_EQ(corr.gain.at(1, 1), 0.f);
  EXPECT_EQ(corr.gain.at(2, 3), 1.25f);
}

TEST(DetectorCalibrationFile, NeverOverwritesUnasked) {
  test::TempDir dir;
  const auto file = dir.path() / "detector-A.tif";
  std::ofstream(file) << "someone's notes";
  const auto refused = write_detector_calibration(file, small_calibration(), false);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.message().find("exists; give --overwrite"), std::string::npos) << refused.message();
  std::ifstream in(file);
  std::string kept;
  std::getline(in, kept);
  EXPECT_EQ(kept, "someone's notes");
  EXPECT_TRUE(write_detector_calibration(file, small_calibration(), true).ok());
  EXPECT_TRUE(load_detector_calibration(file).ok());
  fs::create_symlink(dir.path() / "elsewhere", dir.path() / "link.tif");
  const auto through_link = write_detector_calibration(dir.path() / "link.tif", small_calibration(), true);
  EXPECT_NE(through_link.message().find("not a regular file"), std::string::npos) << through_link.message();
  EXPECT_FALSE(fs::exists(dir.path() / "elsewhere"));
  fs::create_directory(dir.path() / "folder.tif");
  for (bool overwrite : {false, true}) {
    const auto onto_folder = write_detector_calibration(dir.path() / "folder.tif", small_calibration(), overwrite);
    EXPECT_NE(onto_folder.message().find("is a directory"), std::string::npos) << onto_folder.message();
  }
  const auto no_parent = write_detector_calibration(dir.path() / "absent" / "a.tif", small_calibration(), false);
  EXPECT_NE(no_parent.message().find("does not exist"), std::string::npos) << no_parent.message();
  const auto trailing = write_detector_calibration(dir.path().string() + "/sub/", small_calibration(), false);
  EXPECT_NE(trailing.message().find("names a folder"), std::string::npos) << trailing.message();
  // A calibration the loader would refuse is not written.
  calib::DetectorCalibration bad = small_calibration();
  bad.gain.at(0, 0) = std::nanf("");
  const auto non_finite = write_detector_calibration(dir.path() / "nan.tif", bad, false);
  EXPECT_NE(non_finite.message().find("non-finite"), std::string::npos) << non_finite.message();
  bad = small_calibration();
  bad.gain = tracking::Image<float>(5, 5, 1.f);
  EXPECT_FALSE(write_detector_calibration(dir.path() / "size.tif", bad, false).ok());
  EXPECT_FALSE(fs::exists(dir.path() / "nan.tif"));
  EXPECT_FALSE(fs::exists(dir.path() / "size.tif"));
  for (const auto& e : fs::directory_iterator(dir.path()))
    EXPECT_EQ(e.path().string().find(".partial-"), std::string::npos) << "no temporary left: " << e.path();
}

TEST(DetectorCalibrationFile, RefusesDamagedOrLyingFiles) {
  test::TempDir dir;
  const auto good = dir.path() / "good.tif";
  ASSERT_TRUE(write_detector_calibration(good, small_calibration(), false).ok());
  ASSERT_TRUE(load_detector_calibration(good).ok());
  expect_file_refused(dir.path() / "absent.tif", "no such detector calibration file");
  expect_file_refused(dir.path(), "not a regular file");
  std::ofstream(dir.path() / "text.tif") << "not an image";
  expect_file_refused(dir.path() / "text.tif", "not a readable TIFF");
  std::ofstream(dir.path() / "empty.tif");
  expect_file_refused(dir.path() / "empty.tif", "not a readable TIFF");

  // A flipped bit in a map: the hash no longer matches (the lowest mantissa byte of gain(0, 0)).
  const auto flipped = dir.path() / "flipped.tif";
  fs::copy_file(good, flipped);
  set_byte(flipped, page_data_offset(flipped, 1), 0x01);
  expect_file_refused(flipped, "the maps do not match their hash");
  // A byte that makes a value infinite (the exponent of offset(0, 0): 0x7f800000).
  const auto infinite = dir.path() / "infinite.tif";
  fs::copy_file(good, infinite);
  set_byte(infinite, page_data_offset(infinite, 0) + 2, 0x80);
  set_byte(infinite, page_data_offset(infinite, 0) + 3, 0x7f);
  expect_file_refused(infinite, "page 1 (offset_counts) holds a non-finite value at row 1, column 1");

  // Truncated anywhere, to every length short of the whole: refused, never a crash.
  std::ifstream in(good, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto cut_file = dir.path() / "cut.tif";
  int loaded = 0;
  for (std::size_t cut = 0; cut < bytes.size(); ++cut) {
    std::ofstream(cut_file, std::ios::binary | std::ios::trunc).write(bytes.data(), std::streamsize(cut));
    if (load_detector_calibration(cut_file).ok()) {
      ++loaded;
      ADD_FAILURE() << "loaded when cut to " << cut << " of " << bytes.size() << " bytes";
    }
  }
  EXPECT_EQ(loaded, 0);
  std::ofstream(cut_file, std::ios::binary | std::ios::trunc).write(bytes.data(), std::streamsize(bytes.size() - 1));
  expect_file_refused(cut_file, "runs past the end of the file");
}

TEST(DetectorCalibrationFile, RefusesWrongPagesAndMetadata) {
  test::TempDir dir;
  const auto good = dir.path() / "good.tif";
  const calib::DetectorCalibration c = small_calibration();
  ASSERT_TRUE(write_detector_calibration(good, c, false).ok());
  const json meta = metadata_of(good);
  RawFile raw;
  raw.values = pages_of(c);
  const auto made = [&](const std::string& name, const json& m, RawFile r) {
    const auto path = dir.path() / name;
    r.write(path, m.is_null() ? std::string() : m.dump());
    return path;
  };
  ASSERT_TRUE(load_detector_calibration(made("remade.tif", meta, raw)).ok()) << "the hand-made file itself is good";

  // Page counts.
  RawFile three = raw, five = raw;
  three.pages = 3;
  five.pages = 5;
  expect_file_refused(made("three.tif", meta, three), "3 page(s); a detector calibration has 4");
  expect_file_refused(made("five.tif", meta, five), "5 page(s); a detector calibration has 4");
  // Every key is needed.
  for (const auto& [key, value] : meta.items()) {
    json missing = meta;
    missing.erase(key);
    expect_file_refused(made("missing-" + key + ".tif", missing, raw), "metadata key '" + key + "' is missing");
  }
  for (const char* group : {"defect_rule", "defects"})
    for (const auto& [key, value] : meta[group].items()) {
      json missing = meta;
      missing[group].erase(key);
      expect_file_refused(made(std::string("missing-") + group + "-" + key + ".tif", missing, raw),
                     std::string("metadata key '") + group + "." + key + "' is missing");
    }
  // Wrong types and values.
  const auto with = [&](const char* key, const json& value) {
    json m = meta;
    m[key] = value;
    return m;
  };
  expect_file_refused(made("rows-text.tif", with("rows", "six"), raw), "metadata key 'rows' is not an integer");
  expect_file_refused(made("rows-float.tif", with("rows", 6.5), raw), "metadata key 'rows' is not an integer");
  expect_file_refused(made("rows-huge.tif", with("rows", 1e300), raw), "metadata key 'rows' is not an integer");
  expect_file_refused(made("rows-negative.tif", with("rows", -3), raw), "metadata key 'rows' is -3, outside [1, 16384]");
  expect_file_refused(made("open-field.tif", with("open_field_counts", -1), raw), "metadata key 'open_field_counts' is -1");
  expect_file_refused(made("source.tif", with("saturation_source", "guess"), raw), "not option, bits or observed");
  expect_file_refused(made("hash.tif", with("content_hash", "xyz"), raw), "'content_hash' is not 16 hex digits");
  expect_file_refused(made("format.tif", with("format", "something else"), raw), "metadata format is not");
  expect_file_refused(made("renamed.tif", with("detector", "B"), raw), "the maps do not match their hash");  // name in the hash
  expect_file_refused(made("saturation.tif", with("saturation_counts", 65535), raw), "the maps do not match their hash");
  expect_file_refused(made("version.tif", with("version", 1), raw), "version 1 (this build reads version 2");
  json rule = meta;
  rule["defect_rule"]["gain_low"] = 1.0;
  expect_file_refused(made("rule.tif", rule, raw), "metadata defect_rule: the gain limits");
  json masked = meta;
  masked["defects"]["masked"] = 2;
  expect_file_refused(made("masked.tif", masked, raw), "the defect page masks 1 pixels, the metadata says 2");
  expect_file_refused(made("no-metadata.tif", json(), raw), "no metadata");
  json array = json::array({1, 2});
  expect_file_refused(made("array.tif", array, raw), "not a JSON object");
  {
    const auto path = dir.path() / "not-json.tif";
    raw.write(path, "{\"format\": ");
    expect_file_refused(path, "not a JSON object");
  }
  {
    const auto path = dir.path() / "huge-description.tif";
    raw.write(path, meta.dump() + std::string(std::size_t(2) << 20, ' '));
    expect_file_refused(path, "metadata of more than 1 MiB");
  }
  // A tiny file that claims a huge detector: refused before memory is given to it.
  json huge = meta;
  huge["rows"] = huge["cols"] = 16000;
  expect_file_refused(made("huge.tif", huge, raw), "cannot hold four 16000 x 16000 float maps");
  // Pages that disagree with the metadata, or are not float32.
  json smaller = meta;
  smaller["rows"] = 5;
  expect_file_refused(made("smaller.tif", smaller, raw), "page 1 (offset_counts) is 5 x 6 pixels, the metadata says 5 x 5");
  RawFile doubles = raw;
  doubles.bits = 64;
  expect_file_refused(made("doubles.tif", meta, doubles), "is not one-sample 32-bit float");
  // Values the loop cannot use, with a hash that matches them.
  calib::DetectorCalibration negative = c;
  negative.gain.at(0, 0) = -0.5f;
  json negative_meta = meta;
  negative_meta["content_hash"] = calib::detector_calibration_hash(negative);
  RawFile negative_raw = raw;
  negative_raw.values = pages_of(negative);
  expect_file_refused(made("negative.tif", negative_meta, negative_raw), "a negative gain");
  RawFile half = raw;
  half.values[3][0] = 0.5f;
  expect_file_refused(made("half.tif", meta, half), "the defect page holds 0.5");
}

// Random damage anywhere in a good file: the loader answers (mostly refusals), never crashes.
TEST(DetectorCalibrationFile, SurvivesRandomDamage) {
  test::TempDir dir;
  const auto good = dir.path() / "good.tif";
  ASSERT_TRUE(write_detector_calibration(good, small_calibration(), false).ok());
  std::ifstream in(good, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::mt19937 rng(5);
  int refused = 0;
  for (int trial = 0; trial < 400; ++trial) {
    std::string damaged = bytes;
    const int flips = 1 + int(rng() % 4);
    for (int k = 0; k < flips; ++k) damaged[rng() % damaged.size()] = char(rng());
    if (trial % 4 == 0) damaged.resize(rng() % damaged.size());
    const auto path = dir.path() / "damaged.tif";
    std::ofstream(path, std::ios::binary | std::ios::trunc) << damaged;
    refused += !load_detector_calibration(path).ok();
  }
  std::printf("%d of 400 damaged files refused (the rest: damage in the rule's text, the time or tags unread)\n", refused);
  EXPECT_GT(refused, 200) << "most damage is caught";
}

}  // namespace
}  // namespace lftrack::session
