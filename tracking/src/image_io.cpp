// Image files through libpng and libtiff; PFM by hand (a three-line header and raw floats, for
// which no Debian library exists that would be simpler than these few lines).

#include "lftrack/tracking/image_io.hpp"

#include <png.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <sstream>

namespace lftrack::tracking {
namespace {

namespace fs = std::filesystem;

std::string lower_extension(const fs::path& file) {
  std::string ext = file.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext;
}

// Readers open only regular files: a FIFO named like an image would block the open for ever.
Status check_regular(const fs::path& file) {
  std::error_code ec;
  const fs::file_status st = fs::status(file, ec);
  if (ec || !fs::exists(st)) return not_found(file.string() + ": no such file");
  if (!fs::is_regular_file(st)) return corrupt_data(file.string() + ": not a regular file");
  return {};
}


std::vector<uint16_t> windowed_row(const float* src, int cols, const DisplayWindow& w) {
  std::vector<uint16_t> row(static_cast<std::size_t>(cols));
  const double span = w.high > w.low ? w.high - w.low : 1.0;
  for (int c = 0; c < cols; ++c) {
    const double v = std::isfinite(src[c]) ? (src[c] - w.low) / span : 0.0;
    row[static_cast<std::size_t>(c)] = static_cast<uint16_t>(std::lround(std::clamp(v, 0.0, 1.0) * 65535.0));
  }
  return row;
}

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};

Status write_png16(const fs::path& file, const ImageView<const float>& image, const DisplayWindow& w) {
  std::unique_ptr<std::FILE, FileCloser> fp(std::fopen(file.c_str(), "wb"));
  if (!fp) return io_error(file.string() + ": cannot open for writing");
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_write_struct(&png, nullptr);
    return internal_error("libpng: out of memory");
  }
  std::vector<uint16_t> row;
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return io_error(file.string() + ": libpng write failed");
  }
  png_init_io(png, fp.get());
  png_set_IHDR(png, info, static_cast<png_uint_32>(image.cols), static_cast<png_uint_32>(image.rows), 16,
               PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  png_set_swap(png);  // PNG is big-endian; our uint16 are little-endian
  for (int r = 0; r < image.rows; ++r) {
    row = windowed_row(image.row_ptr(r), image.cols, w);
    png_write_row(png, reinterpret_cast<png_const_bytep>(row.data()));
  }
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return {};
}

}  // namespace

Status write_rgb_png(const fs::path& file, const RgbImage& image) {
  if (image.rows <= 0 || image.cols <= 0 || image.rgb.size() != std::size_t(image.rows) * std::size_t(image.cols) * 3)
    return invalid_argument(file.string() + ": an RGB picture of " + std::to_string(image.rows) + " x " +
                            std::to_string(image.cols) + " pixels with " + std::to_string(image.rgb.size()) + " bytes");
  std::unique_ptr<std::FILE, FileCloser> fp(std::fopen(file.c_str(), "wb"));
  if (!fp) return io_error(file.string() + ": cannot open for writing: " + std::strerror(errno));
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_write_struct(&png, nullptr);
    return internal_error("libpng: out of memory");
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return io_error(file.string() + ": libpng write failed");
  }
  png_init_io(png, fp.get());
  png_set_IHDR(png, info, static_cast<png_uint_32>(image.cols), static_cast<png_uint_32>(image.rows), 8,
               PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  for (int r = 0; r < image.rows; ++r)
    png_write_row(png, &image.rgb[std::size_t(r) * std::size_t(image.cols) * 3]);
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  if (std::fflush(fp.get()) != 0 || ::fsync(::fileno(fp.get())) != 0 || std::fclose(fp.release()) != 0)
    return io_error(file.string() + ": write failed: " + std::strerror(errno));
  return {};
}

namespace {

Status write_tiff(const fs::path& file, const ImageView<const float>& image, const ImageWriteOptions& o) {
  TIFFSetWarningHandler(nullptr);
  TIFF* tif = TIFFOpen(file.c_str(), "w");
  if (!tif) return io_error(file.string() + ": cannot open for writing");
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, static_cast<uint32_t>(image.cols));
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, static_cast<uint32_t>(image.rows));
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, o.float_data ? 32 : 16);
  TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, o.float_data ? SAMPLEFORMAT_IEEEFP : SAMPLEFORMAT_UINT);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_NONE);
  TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 1);
  bool ok = true;
  std::vector<float> frow(static_cast<std::size_t>(image.cols));
  for (int r = 0; r < image.rows && ok; ++r) {
    if (o.float_data) {
      std::copy(image.row_ptr(r), image.row_ptr(r) + image.cols, frow.begin());
      ok = TIFFWriteScanline(tif, frow.data(), static_cast<uint32_t>(r), 0) >= 0;
    } else {
      std::vector<uint16_t> row = windowed_row(image.row_ptr(r), image.cols, o.window);
      ok = TIFFWriteScanline(tif, row.data(), static_cast<uint32_t>(r), 0) >= 0;
    }
  }
  TIFFClose(tif);
  return ok ? Status{} : io_error(file.string() + ": libtiff write failed");
}

Status write_pfm(const fs::path& file, const ImageView<const float>& image) {
  std::ofstream out(file, std::ios::binary);
  if (!out) return io_error(file.string() + ": cannot open for writing");
  out << "Pf\n" << image.cols << ' ' << image.rows << "\n-1.0\n";  // -1: little-endian
  for (int r = image.rows - 1; r >= 0; --r) {
    out.write(reinterpret_cast<const char*>(image.row_ptr(r)),
              static_cast<std::streamsize>(sizeof(float) * std::size_t(image.cols)));
  }
  return out ? Status{} : io_error(file.string() + ": write failed");
}

}  // namespace

Status check_claimed_image_size(const fs::path& file, const char* kind, std::uint64_t cols, std::uint64_t rows,
                                std::uint64_t bytes_per_pixel, bool compressed) {
  std::error_code ec;
  const std::uint64_t file_bytes = fs::file_size(file, ec);
  if (ec) return io_error(file.string() + ": " + ec.message());
  const std::string claimed = std::to_string(cols) + " x " + std::to_string(rows);
  if (cols < 1 || rows < 1 || cols > kMaxImageSide || rows > kMaxImageSide)
    return out_of_range(file.string() + ": the " + kind + " header claims " + claimed +
                        " pixels; an image is 1 to " + std::to_string(kMaxImageSide) + " pixels a side");
  const double data_bytes = double(cols) * double(rows) * double(bytes_per_pixel);
  const double most = compressed ? kMaxCompressionRatio * double(file_bytes) : double(file_bytes);
  if (data_bytes > most)
    return corrupt_data(file.string() + ": the " + kind + " header claims " + claimed + " pixels (" +
                        std::to_string(std::uint64_t(data_bytes)) + " bytes of data), more than a file of " +
                        std::to_string(file_bytes) + " bytes can hold" +
                        (compressed ? " even compressed" : ""));
  return {};
}

DisplayWindow percentile_window(const ImageView<const float>& image, double low_pct, double high_pct) {
  std::vector<float> v;
  v.reserve(static_cast<std::size_t>(image.rows) * std::size_t(image.cols));
  for (int r = 0; r < image.rows; ++r)
    for (int c = 0; c < image.cols; ++c)
      if (std::isfinite(image.at(r, c))) v.push_back(image.at(r, c));
  if (v.empty()) return {0, 1};
  auto pick = [&](double pct) {
    const auto k = static_cast<std::size_t>(std::clamp(pct / 100.0, 0.0, 1.0) * double(v.size() - 1));
    std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(k), v.end());
    return double(v[k]);
  };
  DisplayWindow w{pick(low_pct), pick(high_pct)};
  if (!(w.high > w.low)) w.high = w.low + 1.0;
  return w;
}

Status write_image(const fs::path& file, const ImageView<const float>& image, const ImageWriteOptions& o) {
  if (image.empty()) return invalid_argument("empty image");
  const std::string ext = lower_extension(file);
  if (ext == ".png") {
    if (o.float_data) return invalid_argument(file.string() + ": PNG holds no float data; use .tif or .pfm");
    return write_png16(file, image, o.window);
  }
  if (ext == ".tif" || ext == ".tiff") return write_tiff(file, image, o);
  if (ext == ".pfm") return write_pfm(file, image);
  return invalid_argument(file.string() + ": unknown image type '" + ext + "' (use .png, .tif or .pfm)");
}

Result<Image<float>> read_pfm(const fs::path& file) {
  LFTRACK_RETURN_IF_ERROR(check_regular(file));
  std::ifstream in(file, std::ios::binary);
  if (!in) return not_found(file.string() + ": cannot open");
  std::string magic;
  int cols = 0, rows = 0;
  double scale = 0;
  in >> magic >> cols >> rows >> scale;
  if (magic != "Pf" || !in) return corrupt_data(file.string() + ": not a greyscale PFM file");
  if (cols < 1 || rows < 1 || !std::isfinite(scale) || scale == 0) {
    return corrupt_data(file.string() + ": bad PFM size or scale");
  }
  LFTRACK_RETURN_IF_ERROR(check_claimed_image_size(file, "PFM", std::uint64_t(cols), std::uint64_t(rows), 4, false));
  in.get();  // the single whitespace after the scale
  Image<float> image(rows, cols);
  for (int r = rows - 1; r >= 0; --r) {
    in.read(reinterpret_cast<char*>(&image.at(r, 0)),
            static_cast<std::streamsize>(sizeof(float) * std::size_t(cols)));
  }
  if (!in) return corrupt_data(file.string() + ": PFM data is truncated");
  if (scale > 0) {  // big-endian data
    for (float& v : image.pixels()) {
      uint32_t u;
      std::memcpy(&u, &v, 4);
      u = __builtin_bswap32(u);
      std::memcpy(&v, &u, 4);
    }
  }
  return image;
}

Result<Image<float>> read_tiff(const fs::path& file) {
  LFTRACK_RETURN_IF_ERROR(check_regular(file));
  TIFFSetWarningHandler(nullptr);
  TIFFSetErrorHandler(nullptr);
  TIFF* tif = TIFFOpen(file.c_str(), "r");
  if (!tif) return corrupt_data(file.string() + ": not a readable TIFF file");
  uint32_t w = 0, h = 0;
  uint16_t bits = 0, spp = 1, fmt = SAMPLEFORMAT_UINT;
  TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &w);
  TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &h);
  TIFFGetField(tif, TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &spp);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &fmt);
  uint16_t compression = COMPRESSION_NONE;
  TIFFGetFieldDefaulted(tif, TIFFTAG_COMPRESSION, &compression);
  const bool supported =
      spp == 1 && ((fmt == SAMPLEFORMAT_UINT && (bits == 8 || bits == 16)) || (fmt == SAMPLEFORMAT_IEEEFP && bits == 32));
  if (!supported) {
    TIFFClose(tif);
    return unsupported(file.string() + ": TIFF must be one-sample 8/16-bit unsigned or 32-bit float");
  }
  if (Status s = check_claimed_image_size(file, "TIFF", w, h, bits / 8, compression != COMPRESSION_NONE); !s.ok()) {
    TIFFClose(tif);
    return s;
  }
  Image<float> image(static_cast<int>(h), static_cast<int>(w));
  std::vector<unsigned char> line(static_cast<std::size_t>(TIFFScanlineSize(tif)));
  for (uint32_t r = 0; r < h; ++r) {
    if (TIFFReadScanline(tif, line.data(), r, 0) < 0) {
      TIFFClose(tif);
      return corrupt_data(file.string() + ": TIFF data is truncated or unreadable");
    }
    for (uint32_t c = 0; c < w; ++c) {
      float v;
      if (bits == 8)
        v = line[c];
      else if (bits == 16) {
        uint16_t u;
        std::memcpy(&u, &line[2 * c], 2);
        v = u;
      } else
        std::memcpy(&v, &line[4 * c], 4);
      image.at(int(r), int(c)) = v;
    }
  }
  TIFFClose(tif);
  return image;
}

Result<Image<float>> read_png(const fs::path& file) {
  LFTRACK_RETURN_IF_ERROR(check_regular(file));
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&img, file.c_str())) {
    return corrupt_data(file.string() + ": not a readable PNG file");
  }
  if (Status s = check_claimed_image_size(file, "PNG", img.width, img.height, 2, true); !s.ok()) {
    png_image_free(&img);
    return s;
  }
  img.format = PNG_FORMAT_LINEAR_Y;  // 16-bit linear greyscale
  std::vector<uint16_t> buffer(PNG_IMAGE_SIZE(img) / 2);
  if (!png_image_finish_read(&img, nullptr, buffer.data(), 0, nullptr)) {
    png_image_free(&img);
    return corrupt_data(file.string() + ": PNG data is truncated or unreadable");
  }
  Image<float> image(static_cast<int>(img.height), static_cast<int>(img.width));
  std::copy(buffer.begin(), buffer.end(), image.pixels().begin());
  return image;
}

}  // namespace lftrack::tracking
