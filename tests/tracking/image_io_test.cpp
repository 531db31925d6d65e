#include <gtest/gtest.h>

#include "lftrack/tracking/image_io.hpp"
#include "lying_images.hpp"
#include "test_data.hpp"

namespace lftrack::tracking {
namespace {

Image<float> ramp(int rows, int cols) {
  Image<float> im(rows, cols);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) im.at(r, c) = 0.25f * float(r) + 0.01f * float(c) - 1.0f;
  return im;
}

TEST(ImageIo, FloatDataRoundTripsThroughPfmAndTiff) {
  test::TempDir dir;
  const Image<float> im = ramp(13, 7);
  ImageWriteOptions o;
  o.float_data = true;
  ASSERT_TRUE(write_image(dir.path() / "a.pfm", im.view(), o).ok());
  ASSERT_TRUE(write_image(dir.path() / "a.tif", im.view(), o).ok());
  auto pfm = read_pfm(dir.path() / "a.pfm");
  auto tif = read_tiff(dir.path() / "a.tif");
  ASSERT_TRUE(pfm.ok() && tif.ok());
  EXPECT_EQ(pfm->pixels(), im.pixels());  // row order preserved (PFM stores bottom-up)
  EXPECT_EQ(tif->pixels(), im.pixels());
}

TEST(ImageIo, SixteenBitOutputsAreWindowed) {
  test::TempDir dir;
  const Image<float> im = ramp(9, 5);  // -1 .. 1.04
  ImageWriteOptions o;
  o.window = {0.0, 1.0};
  ASSERT_TRUE(write_image(dir.path() / "a.png", im.view(), o).ok());
  ASSERT_TRUE(write_image(dir.path() / "a.tif", im.view(), o).ok());
  for (const char* name : {"a.png", "a.tif"}) {
    auto back = std::string(name) == "a.png" ? read_png(dir.path() / name) : read_tiff(dir.path() / name);
    ASSERT_TRUE(back.ok()) << name;
    EXPECT_EQ(back->at(0, 0), 0.0f) << name;                // below the window: black
    EXPECT_EQ(back->at(8, 4), 65535.0f) << name;            // above: white
    EXPECT_NEAR(back->at(6, 0), 0.5 * 65535, 1.0) << name;  // 0.5 in the window's middle
  }
}

TEST(ImageIo, RejectsUnknownExtensionAndFloatPng) {
  test::TempDir dir;
  const Image<float> im = ramp(3, 3);
  EXPECT_FALSE(write_image(dir.path() / "a.jpg", im.view(), {}).ok());
  ImageWriteOptions o;
  o.float_data = true;
  EXPECT_FALSE(write_image(dir.path() / "a.png", im.view(), o).ok());
}

TEST(ImageIo, TruncatedFilesFailCleanly) {
  test::TempDir dir;
  const Image<float> im = ramp(32, 32);
  ImageWriteOptions o;
  o.float_data = true;
  ASSERT_TRUE(write_image(dir.path() / "a.pfm", im.view(), o).ok());
  std::filesystem::resize_file(dir.path() / "a.pfm", 200);
  EXPECT_FALSE(read_pfm(dir.path() / "a.pfm").ok());
  EXPECT_FALSE(read_tiff(dir.path() / "missing.tif").ok());
}

// Headers that claim more pixels than their files hold are refused at once, before anything
// is allocated (a 65535 x 65535 TIFF once took 52 s and 16.9 GB to fail).
TEST(ImageIo, HeadersClaimingMorePixelsThanTheFileHoldsAreRefused) {
  test::TempDir dir;
  ASSERT_TRUE(test::write_lying_tiff(dir.path() / "big.tif", 65535, 65535));
  ASSERT_TRUE(test::write_lying_tiff(dir.path() / "deflated.tif", 16000, 16000, true));
  ASSERT_TRUE(test::write_lying_tiff(dir.path() / "wide.tif", 70000, 2));
  ASSERT_TRUE(test::write_lying_png(dir.path() / "big.png", 100000, 100000));
  ASSERT_TRUE(test::write_lying_png(dir.path() / "tall.png", 4000, 4000));
  const std::pair<const char*, const char*> cases[] = {
      {"big.tif", "claims 65535 x 65535 pixels; an image is 1 to 16384 pixels a side"},
      {"deflated.tif", "claims 16000 x 16000 pixels (512000000 bytes of data), more than a file of"},
      {"wide.tif", "claims 70000 x 2 pixels; an image is 1 to 16384"},
      {"big.png", "claims 100000 x 100000 pixels; an image is 1 to 16384"},
      {"tall.png", "bytes can hold even compressed"}};
  for (const auto& [name, expected] : cases) {
    const std::filesystem::path file = dir.path() / name;
    auto image = std::string(name).ends_with(".png") ? read_png(file) : read_tiff(file);
    ASSERT_FALSE(image.ok()) << name;
    EXPECT_NE(image.status().message().find(expected), std::string::npos) << image.status().message();
  }
  // A real image of the same sizes still reads.
  ImageWriteOptions o;
  o.float_data = true;
  ASSERT_TRUE(write_image(dir.path() / "ok.tif", ramp(300, 200).view(), o).ok());
  EXPECT_TRUE(read_tiff(dir.path() / "ok.tif").ok());
  ASSERT_TRUE(write_image(dir.path() / "ok.png", ramp(300, 200).view(), {}).ok());
  EXPECT_TRUE(read_png(dir.path() / "ok.png").ok());
}

TEST(ImageIo, PercentileWindowIgnoresOutliers) {
  Image<float> im(10, 10, 1.0f);
  for (int c = 0; c < 10; ++c) im.at(5, c) = 2.0f;
  im.at(0, 0) = 1000.0f;
  const DisplayWindow w = percentile_window(im.view(), 0.0, 98.0);
  EXPECT_FLOAT_EQ(float(w.low), 1.0f);
  EXPECT_FLOAT_EQ(float(w.high), 2.0f);
}

}  // namespace
}  // namespace lftrack::tracking
