#pragma once
// Writing and reading DRRs and frames.
//
// - .png  : 16-bit greyscale, windowed: [window.low, window.high] -> [0, 65535], clamped.
// - .tif  : 16-bit greyscale windowed like PNG, or float32 data when `float_data` is set.
// - .pfm  : float32 data (Portable Float Map; rows stored bottom-up as the format says).
// Windowed writes map larger line integrals (bone) to brighter pixels.

#include <cstdint>
#include <filesystem>
#include <vector>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {

struct DisplayWindow {
  double low = 0;
  double high = 1;
};

// A window from the `low_percentile` and `high_percentile` (0..100) of the image's values.
DisplayWindow percentile_window(const ImageView<const float>& image, double low_percentile = 0.5,
                                double high_percentile = 99.5);

struct ImageWriteOptions {
  DisplayWindow window;     // for 16-bit outputs
  bool float_data = false;  // .tif: write float32 instead of windowed 16-bit
};

// Writes by extension (.png, .tif/.tiff, .pfm); any other extension is an error.
Status write_image(const std::filesystem::path& file, const ImageView<const float>& image,
                   const ImageWriteOptions& options);

// An 8-bit RGB picture, top row first, 3 bytes a pixel: what a person looks at (a set-up picture
// with its overlays), never data.
struct RgbImage {
  int rows = 0;
  int cols = 0;
  std::vector<std::uint8_t> rgb;  // rows * cols * 3
  RgbImage() = default;
  RgbImage(int r, int c) : rows(r), cols(c), rgb(std::size_t(r) * std::size_t(c) * 3, 0) {}
  // Sets a pixel; one outside the picture is ignored (overlays may leave it).
  void set(int row, int col, std::uint8_t red, std::uint8_t green, std::uint8_t blue) {
    if (row < 0 || col < 0 || row >= rows || col >= cols) return;
    std::uint8_t* p = &rgb[(std::size_t(row) * std::size_t(cols) + std::size_t(col)) * 3];
    p[0] = red;
    p[1] = green;
    p[2] = blue;
  }
};
Status write_rgb_png(const std::filesystem::path& file, const RgbImage& image);

// Every reader checks the size its header claims before allocating: at most kMaxImageSide
// pixels a side, and no more data than the file can hold (uncompressed: the pixels' bytes;
// compressed: kMaxCompressionRatio times the file's size, above what deflate or LZW reach), so
// a 500 KB file claiming 65535 x 65535 pixels is refused at once with both sizes named.
inline constexpr std::uint32_t kMaxImageSide = 16384;
inline constexpr double kMaxCompressionRatio = 4096;
// That check, for any reader of image files (the frame readers in drivers/ use it too): `kind`
// names the format in the message.
Status check_claimed_image_size(const std::filesystem::path& file, const char* kind, std::uint64_t cols,
                                std::uint64_t rows, std::uint64_t bytes_per_pixel, bool compressed);

Result<Image<float>> read_pfm(const std::filesystem::path& file);
// Reads a greyscale TIFF (8/16-bit unsigned or 32-bit float, one sample per pixel) as float.
Result<Image<float>> read_tiff(const std::filesystem::path& file);
// Reads a greyscale 16-bit PNG as float (8-bit files are decoded from sRGB by libpng).
Result<Image<float>> read_png(const std::filesystem::path& file);

}  // namespace lftrack::tracking
