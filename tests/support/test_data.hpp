#pragma once
// Locating the shared CT data (../shared/data next to the repository) from tests.
//
// Tests that need the data call LFTRACK_REQUIRE_SHARED_DATA(path): when the folder is missing
// they skip with a message, unless LFTRACK_REQUIRE_DATA=1 (CI), where a missing folder fails.

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace lftrack::test {

inline std::filesystem::path shared_data_dir() {
  if (const char* env = std::getenv("LFTRACK_DATA_DIR")) return env;
  return std::filesystem::path(LFTRACK_SOURCE_DIR) / ".." / "shared" / "data";
}

inline std::filesystem::path pancreas_dicom() {
  return shared_data_dir() / "ct/pancreas-ct-cb001/dicom";
}
inline std::filesystem::path totalseg_example() {
  return shared_data_dir() / "ct/totalseg/example_ct.nii.gz";
}
inline std::filesystem::path totalseg_aorta() {
  return shared_data_dir() / "ct/totalseg/aorta_ct_cropped.nii.gz";
}

// A scene of the lumbar DICOM CT's L3 vertebral body seen by two coarse oblique views (128 x 128
// pixels of 1.6 mm), ray cast: quick to register. `roi_extra` is added under `roi:` (indented
// two spaces, e.g. a mask).
inline std::string lumbar_two_coarse_views_scene(const std::string& roi_extra = "") {
  std::string s = "version: 1\nct: {path: " + pancreas_dicom().string() +
                  "}\nroi:\n  centre_mm: [6, 107, 184.91]\n  size_mm: [56, 48, 50]\n" + roi_extra +
                  "registration_origin_mm: [6, 107, 183]\ndetectors:\n";
  for (const char* v : {"A: [0.70710678, -0.70710678, 0]", "B: [-0.70710678, -0.70710678, 0]"}) {
    const std::string text(v);
    s += "  - name: " + text.substr(0, 1) + "\n    rows: 128\n    cols: 128\n    pitch_mm: 1.6\n" +
         "    isocentric: {source_direction: " + text.substr(3) +
         ", up: [0, 0, 1], source_to_isocentre_mm: 1500, source_to_detector_mm: 2100}\n";
  }
  return s + "tracking: {renderer: siddon}\n";
}

inline bool data_required() {
  const char* env = std::getenv("LFTRACK_REQUIRE_DATA");
  return env && std::string(env) == "1";
}

// What tests build once and share across test processes (light fields): a folder in the build
// tree, `test-cache`, which `make clean` removes. Whatever is kept there must be checked when read
// back (a light field is, against its CT and plan; its folder names the lftrack build), so a
// stale entry is rebuilt, never trusted.
inline std::filesystem::path test_cache_dir() { return std::filesystem::path(LFTRACK_TEST_CACHE_DIR); }

// A GoogleTest parameter name for a shipped scene file: "lumbar-ct-clinical.yaml" gives
// "lumbar_ct_clinical".
inline std::string scene_test_name(std::string file) {
  file = file.substr(0, file.find('.'));
  for (char& c : file)
    if (c == '-') c = '_';
  return file;
}

// A fresh, empty temporary folder named after the running test; removed by the destructor.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

}  // namespace lftrack::test

#define LFTRACK_REQUIRE_SHARED_DATA(path)                                                \
  do {                                                                                   \
    if (!std::filesystem::exists(path)) {                                                \
      if (::lftrack::test::data_required()) {                                            \
        FAIL() << "shared CT data missing at " << (path) << " (LFTRACK_REQUIRE_DATA=1)"; \
      }                                                                                  \
      GTEST_SKIP() << "shared CT data not found at " << (path)                           \
                   << "; clone next to ../shared to run this test";                      \
    }                                                                                    \
  } while (false)

#define LFTRACK_REQUIRE_PLASTIMATCH()                                                 \
  do {                                                                                \
    if (!::lftrack::studies::plastimatch_available()) {                               \
      if (::lftrack::test::data_required()) FAIL() << "plastimatch is not installed"; \
      GTEST_SKIP() << "plastimatch is not installed (scripts/setup.sh installs it)";  \
    }                                                                                 \
  } while (false)
