// 16-bit frame files through libtiff and libpng (the field's libraries for both formats).

#include "lftrack/drivers/frame_files.hpp"

#include <png.h>
#include <sys/stat.h>
#include <tiffio.h>

#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <string>

#include "lftrack/tracking/image_io.hpp"

namespace lftrack::drivers {
namespace {

enum class FileType { kTiff, kPng, kOther };

FileType type_of(const char* path) {
  const char* dot = std::strrchr(path, '.');
  if (dot == nullptr) return FileType::kOther;
  if (strcasecmp(dot, ".tif") == 0 || strcasecmp(dot, ".tiff") == 0) return FileType::kTiff;
  if (strcasecmp(dot, ".png") == 0) return FileType::kPng;
  return FileType::kOther;
}

std::string size_text(std::uint32_t cols, std::uint32_t rows) {
  return std::to_string(cols) + " x " + std::to_string(rows);
}

Status wrong_size(const char* path, std::uint32_t cols, std::uint32_t rows, int want_cols, int want_rows) {
  return out_of_range(std::string(path) + ": the frame is " + size_text(cols, rows) +
                      " pixels, the detector " +
                      size_text(std::uint32_t(want_cols), std::uint32_t(want_rows)));
}

// libpng reports errors through these; ours say nothing (the status says it) and unwind.
void png_error_quietly(png_structp png, png_const_charp) {
  png_longjmp(png, 1);
}
void png_warning_quietly(png_structp, png_const_charp) {}

Status read_tiff_frame(const char* path, tracking::ImageView<std::uint16_t> out) {
  TIFFSetWarningHandler(nullptr);
  TIFFSetErrorHandler(nullptr);
  TIFF* tif = TIFFOpen(path, "r");
  if (tif == nullptr) return corrupt_data(std::string(path) + ": not a readable TIFF file");
  std::uint32_t cols = 0, rows = 0;
  std::uint16_t bits = 0, samples = 1, format = SAMPLEFORMAT_UINT;
  TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &cols);
  TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &rows);
  TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &samples);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &format);
  Status status;
  if (bits != 16 || samples != 1 || format != SAMPLEFORMAT_UINT || TIFFIsTiled(tif)) {
    status = unsupported(std::string(path) + ": a frame must be a one-sample 16-bit unsigned TIFF in strips");
  } else if (cols != std::uint32_t(out.cols) || rows != std::uint32_t(out.rows)) {
    status = wrong_size(path, cols, rows, out.cols, out.rows);
  } else {
    for (std::uint32_t r = 0; r < rows && status.ok(); ++r)
      if (TIFFReadScanline(tif, out.row_ptr(int(r)), r, 0) < 0)
        status = corrupt_data(std::string(path) + ": TIFF data is truncated or unreadable");
  }
  TIFFClose(tif);
  return status;
}

Status read_png_frame(const char* path, tracking::ImageView<std::uint16_t> out) {
  std::FILE* file = std::fopen(path, "rb");
  if (file == nullptr) return corrupt_data(std::string(path) + ": cannot open");
  png_structp png =
      png_create_read_struct(PNG_LIBPNG_VER_STRING, nullptr, png_error_quietly, png_warning_quietly);
  png_infop info = png != nullptr ? png_create_info_struct(png) : nullptr;
  Status status;
  if (info == nullptr) {
    status = internal_error("libpng: out of memory");
  } else if (setjmp(png_jmpbuf(png))) {
    status = corrupt_data(std::string(path) + ": not a readable PNG file, or its data is truncated");
  } else {
    png_init_io(png, file);
    png_read_info(png, info);
    const png_uint_32 cols = png_get_image_width(png, info), rows = png_get_image_height(png, info);
    if (png_get_bit_depth(png, info) != 16 || png_get_color_type(png, info) != PNG_COLOR_TYPE_GRAY) {
      status = unsupported(std::string(path) + ": a frame must be a 16-bit greyscale PNG");
    } else if (cols != png_uint_32(out.cols) || rows != png_uint_32(out.rows)) {
      status = wrong_size(path, cols, rows, out.cols, out.rows);
    } else {
      png_set_swap(png);  // PNG is big-endian
      const int passes = png_set_interlace_handling(png);
      for (int pass = 0; pass < passes; ++pass)
        for (png_uint_32 r = 0; r < rows; ++r)
          png_read_row(png, reinterpret_cast<png_bytep>(out.row_ptr(int(r))), nullptr);
      png_read_end(png, nullptr);
    }
  }
  png_destroy_read_struct(&png, &info, nullptr);
  std::fclose(file);
  return status;
}

Status write_tiff_frame(const char* path, tracking::ImageView<const std::uint16_t> frame) {
  TIFFSetWarningHandler(nullptr);
  TIFFSetErrorHandler(nullptr);
  TIFF* tif = TIFFOpen(path, "w");
  if (tif == nullptr) return io_error(std::string(path) + ": cannot open for writing");
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, std::uint32_t(frame.cols));
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, std::uint32_t(frame.rows));
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 16);
  TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_UINT);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_NONE);
  TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, std::uint32_t(frame.rows));
  bool ok = true;
  for (int r = 0; r < frame.rows && ok; ++r)
    ok = TIFFWriteScanline(tif, const_cast<std::uint16_t*>(frame.row_ptr(r)), std::uint32_t(r), 0) >= 0;
  TIFFClose(tif);
  return ok ? Status{} : io_error(std::string(path) + ": TIFF write failed");
}

Status write_png_frame(const char* path, tracking::ImageView<const std::uint16_t> frame) {
  std::FILE* file = std::fopen(path, "wb");
  if (file == nullptr) return io_error(std::string(path) + ": cannot open for writing");
  png_structp png =
      png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, png_error_quietly, png_warning_quietly);
  png_infop info = png != nullptr ? png_create_info_struct(png) : nullptr;
  Status status;
  if (info == nullptr) {
    status = internal_error("libpng: out of memory");
  } else if (setjmp(png_jmpbuf(png))) {
    status = io_error(std::string(path) + ": PNG write failed");
  } else {
    png_init_io(png, file);
    png_set_IHDR(png, info, png_uint_32(frame.cols), png_uint_32(frame.rows), 16, PNG_COLOR_TYPE_GRAY,
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    png_set_swap(png);
    for (int r = 0; r < frame.rows; ++r)
      png_write_row(png, reinterpret_cast<png_const_bytep>(frame.row_ptr(r)));
    png_write_end(png, nullptr);
  }
  png_destroy_write_struct(&png, &info);
  if (std::fclose(file) != 0 && status.ok()) status = io_error(std::string(path) + ": PNG write failed");
  return status;
}

}  // namespace

Status read_frame_file(const char* path, tracking::ImageView<std::uint16_t> out) {
  struct stat st {};
  if (::stat(path, &st) != 0) return not_found(std::string(path) + ": no such frame file");
  // A FIFO or device named like a frame would block the read for ever (an outside probe hung a
  // replay that way); a frame is a regular file.
  if (!S_ISREG(st.st_mode)) return corrupt_data(std::string(path) + ": not a regular file");
  switch (type_of(path)) {
    case FileType::kTiff:
      return read_tiff_frame(path, out);
    case FileType::kPng:
      return read_png_frame(path, out);
    case FileType::kOther:
      break;
  }
  return unsupported(std::string(path) + ": a frame file is .tif, .tiff or .png");
}

Status frame_file_size(const char* path, int* rows, int* cols) {
  struct stat st {};
  if (::stat(path, &st) != 0) return not_found(std::string(path) + ": no such frame file");
  if (!S_ISREG(st.st_mode)) return corrupt_data(std::string(path) + ": not a regular file");
  std::uint32_t w = 0, h = 0;
  bool compressed = true;  // PNG always is
  if (type_of(path) == FileType::kTiff) {
    TIFFSetWarningHandler(nullptr);
    TIFFSetErrorHandler(nullptr);
    TIFF* tif = TIFFOpen(path, "r");
    if (tif == nullptr) return corrupt_data(std::string(path) + ": not a readable TIFF file");
    TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &w);
    TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &h);
    std::uint16_t compression = COMPRESSION_NONE;
    TIFFGetFieldDefaulted(tif, TIFFTAG_COMPRESSION, &compression);
    compressed = compression != COMPRESSION_NONE;
    TIFFClose(tif);
  } else if (type_of(path) == FileType::kPng) {
    std::FILE* file = std::fopen(path, "rb");
    if (file == nullptr) return corrupt_data(std::string(path) + ": cannot open");
    png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, nullptr, png_error_quietly, png_warning_quietly);
    png_infop info = png != nullptr ? png_create_info_struct(png) : nullptr;
    volatile bool ok = false;  // set after setjmp: volatile across the longjmp
    if (info != nullptr && !setjmp(png_jmpbuf(png))) {
      png_init_io(png, file);
      png_read_info(png, info);
      w = png_get_image_width(png, info);
      h = png_get_image_height(png, info);
      ok = true;
    }
    png_destroy_read_struct(&png, &info, nullptr);
    std::fclose(file);
    if (!ok) return corrupt_data(std::string(path) + ": not a readable PNG file");
  } else {
    return unsupported(std::string(path) + ": a frame file is .tif, .tiff or .png");
  }
  if (w == 0 || h == 0 || w > 16384 || h > 16384)
    return out_of_range(std::string(path) + ": the header claims " + size_text(w, h) +
                        " pixels; a frame is 1 to 16384 pixels a side");
  // No more 16-bit pixels than the file can hold, checked before anyone allocates the frame.
  LFTRACK_RETURN_IF_ERROR(tracking::check_claimed_image_size(
      path, type_of(path) == FileType::kTiff ? "TIFF" : "PNG", w, h, sizeof(std::uint16_t), compressed));
  *rows = static_cast<int>(h);
  *cols = static_cast<int>(w);
  return {};
}

Status write_frame_file(const char* path, tracking::ImageView<const std::uint16_t> frame) {
  if (frame.empty()) return invalid_argument("an empty frame");
  switch (type_of(path)) {
    case FileType::kTiff:
      return write_tiff_frame(path, frame);
    case FileType::kPng:
      return write_png_frame(path, frame);
    case FileType::kOther:
      break;
  }
  return unsupported(std::string(path) + ": a frame file is .tif, .tiff or .png");
}

}  // namespace lftrack::drivers
