#pragma once
// Writes small synthetic DICOM CT slices for reader tests, with every attribute the reader
// checks under the test's control.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace lftrack::test {

struct SyntheticSlice {
  std::string series_uid = "1.2.826.0.1.3680043.2.1125.1";
  std::string frame_of_reference_uid = "1.2.826.0.1.3680043.2.1125.5";  // empty: none written
  std::string modality = "CT";
  int rows = 8;
  int cols = 6;
  Eigen::Vector3d position_mm{-10.0, -20.0, 0.0};
  Eigen::Vector3d row_cosine{1, 0, 0};          // IOP[0..2]
  Eigen::Vector3d col_cosine{0, 1, 0};          // IOP[3..5]
  Eigen::Vector2d pixel_spacing_mm{0.5, 0.75};  // between rows, between columns
  double slope = 1.0;
  double intercept = -1024.0;
  std::string slope_text;        // written instead of `slope` when not empty (bad text on purpose)
  bool omit_intercept = false;   // no RescaleIntercept at all
  int bits_stored = 16;              // BitsStored (HighBit one less); signed values
  std::vector<std::int16_t> stored;  // rows * cols raw values; empty: a pattern from `seed`
  int seed = 0;
  bool mpeg2_pixel_data = false;  // encapsulate as MPEG2 (a syntax GDCM cannot decode)
};

// Writes one slice; returns false on failure.
bool write_synthetic_slice(const std::filesystem::path& file, const SyntheticSlice& slice);

// The raw stored value the pattern gives at (row, col) for `seed`.
std::int16_t pattern_value(int seed, int row, int col);

// Writes `count` slices of `base` along the slice normal at positions z0 + k * spacing.
void write_synthetic_series(const std::filesystem::path& folder, const SyntheticSlice& base, int count,
                            double spacing_mm);

}  // namespace lftrack::test
