// Frame files: exact 16-bit round trips through TIFF and PNG, and a status for every bad file.

#include "lftrack/drivers/frame_files.hpp"

#include <gtest/gtest.h>
#include <tiffio.h>

#include <fstream>

#include "lying_images.hpp"
#include "test_data.hpp"

namespace lftrack::drivers {
namespace {

using tracking::Image;

Image<std::uint16_t> ramp(int rows, int cols) {
  Image<std::uint16_t> image(rows, cols);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) image.at(r, c) = static_cast<std::uint16_t>((r * 977 + c * 131) % 65536);
  image.at(0, 0) = 0;
  image.at(rows - 1, cols - 1) = 65535;
  return image;
}

class FrameFiles : public ::testing::TestWithParam<const char*> {
 protected:
  std::string path(const std::string& name) const { return (dir_.path() / name).string(); }
  test::TempDir dir_;
};

TEST_P(FrameFiles, RoundTripIsExact) {
  const Image<std::uint16_t> frame = ramp(37, 53);
  const std::string file = path(std::string("frame") + GetParam());
  ASSERT_TRUE(write_frame_file(file.c_str(), frame.view()).ok());
  Image<std::uint16_t> back(37, 53);
  const Status s = read_frame_file(file.c_str(), back.view());
  ASSERT_TRUE(s.ok()) << s.message();
  EXPECT_EQ(back.pixels(), frame.pixels());
}

TEST_P(FrameFiles, WrongSizeIsOutOfRangeAndNamesBothSizes) {
  const std::string file = path(std::string("frame") + GetParam());
  ASSERT_TRUE(write_frame_file(file.c_str(), ramp(10, 20).view()).ok());
  Image<std::uint16_t> back(20, 10);
  const Status s = read_frame_file(file.c_str(), back.view());
  EXPECT_EQ(s.code(), StatusCode::kOutOfRange);
  EXPECT_NE(s.message().find("20 x 10 pixels, the detector 10 x 20"), std::string::npos) << s.message();
}

TEST_P(FrameFiles, TruncatedOrGarbageIsCorrupt) {
  const std::string file = path(std::string("frame") + GetParam());
  ASSERT_TRUE(write_frame_file(file.c_str(), ramp(64, 64).view()).ok());
  std::filesystem::resize_file(file, std::filesystem::file_size(file) / 2);
  Image<std::uint16_t> back(64, 64);
  EXPECT_EQ(read_frame_file(file.c_str(), back.view()).code(), StatusCode::kCorruptData);
  std::ofstream(file, std::ios::trunc) << "not an image at all";
  EXPECT_EQ(read_frame_file(file.c_str(), back.view()).code(), StatusCode::kCorruptData);
}

INSTANTIATE_TEST_SUITE_P(Formats, FrameFiles, ::testing::Values(".tif", ".png"));

// A header that claims more 16-bit pixels than its file holds is refused by the size query
// that callers (calibrate detector, replay) ask before allocating a frame.
TEST(FrameFileErrors, HeadersClaimingMorePixelsThanTheFileHoldsAreRefused) {
  test::TempDir dir;
  ASSERT_TRUE(test::write_lying_tiff(dir.path() / "a.tif", 4000, 4000));
  ASSERT_TRUE(test::write_lying_tiff(dir.path() / "b.tif", 16000, 16000, true));
  ASSERT_TRUE(test::write_lying_png(dir.path() / "c.png", 4000, 4000));
  ASSERT_TRUE(test::write_lying_png(dir.path() / "d.png", 100000, 100000));
  for (const char* name : {"a.tif", "b.tif", "c.png", "d.png"}) {
    int rows = 0, cols = 0;
    const Status s = frame_file_size((dir.path() / name).c_str(), &rows, &cols);
    ASSERT_FALSE(s.ok()) << name;
    const bool absurd = std::string(name) == "d.png";
    EXPECT_NE(s.message().find(absurd ? "a frame is 1 to 16384 pixels a side" : "bytes can hold"), std::string::npos)
        << s.message();
    EXPECT_EQ(rows, 0);
  }
  Image<std::uint16_t> frame = ramp(64, 48);
  for (const char* name : {"ok.tif", "ok.png"}) {
    const std::string file = (dir.path() / name).string();
    ASSERT_TRUE(write_frame_file(file.c_str(), frame.view()).ok());
    int rows = 0, cols = 0;
    ASSERT_TRUE(frame_file_size(file.c_str(), &rows, &cols).ok()) << name;
    EXPECT_EQ(rows, 64);
    EXPECT_EQ(cols, 48);
  }
}

TEST(FrameFileErrors, MissingFileIsNotFound) {
  Image<std::uint16_t> back(4, 4);
  EXPECT_EQ(read_frame_file("/nonexistent/frame.tif", back.view()).code(), StatusCode::kNotFound);
}

TEST(FrameFileErrors, UnknownExtensionIsUnsupported) {
  test::TempDir dir;
  const std::string file = (dir.path() / "frame.bmp").string();
  std::ofstream(file) << "x";
  Image<std::uint16_t> image(4, 4);
  EXPECT_EQ(read_frame_file(file.c_str(), image.view()).code(), StatusCode::kUnsupported);
  EXPECT_EQ(write_frame_file(file.c_str(), image.view()).code(), StatusCode::kUnsupported);
}

TEST(FrameFileErrors, EightBitTiffIsUnsupported) {
  test::TempDir dir;
  const std::string file = (dir.path() / "frame8.tif").string();
  TIFF* tif = TIFFOpen(file.c_str(), "w");
  ASSERT_NE(tif, nullptr);
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, 4u);
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 4u);
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 8);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
  unsigned char row[4] = {1, 2, 3, 4};
  for (std::uint32_t r = 0; r < 4; ++r) TIFFWriteScanline(tif, row, r, 0);
  TIFFClose(tif);
  Image<std::uint16_t> image(4, 4);
  const Status s = read_frame_file(file.c_str(), image.view());
  EXPECT_EQ(s.code(), StatusCode::kUnsupported) << s.message();
}

}  // namespace
}  // namespace lftrack::drivers
