// Frame files (drivers/frame_files.hpp, 16-bit TIFF and PNG, as replay and calibrate detector
// read them) and images (tracking/image_io.hpp, TIFF, PNG and PFM, as register --images and
// calibrate views read them). The first input byte picks the format.
#include "fuzz_input.hpp"
#include "lftrack/drivers/frame_files.hpp"
#include "lftrack/tracking/image_io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  if (size < 1) return 0;
  const char* names[] = {"frame.tif", "frame.png", "image.pfm"};
  const int kind = data[0] % 3;
  const auto file = fuzz::write_input(names[kind], data + 1, size - 1);
  if (kind < 2) {
    int rows = 0, cols = 0;
    const Status s = drivers::frame_file_size(file.c_str(), &rows, &cols);
    fuzz::expect_reason(s);
    tracking::Image<std::uint16_t> frame(s.ok() && rows * cols <= 1 << 22 ? rows : 8, s.ok() && rows * cols <= 1 << 22 ? cols : 8);
    fuzz::expect_reason(drivers::read_frame_file(file.c_str(), frame.view()));
    auto image = kind == 0 ? tracking::read_tiff(file) : tracking::read_png(file);
    if (!image.ok()) fuzz::expect_reason(image.status());
  } else {
    auto image = tracking::read_pfm(file);
    if (!image.ok()) fuzz::expect_reason(image.status());
  }
  return 0;
}
