#include "detector_calibration_tiff.hpp"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>

namespace lftrack::session::calibration_tiff {

namespace fs = std::filesystem;

namespace {

Status write_page(TIFF* tif, const float* data, int rows, int cols, const std::string& description,
                  int page) {
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, std::uint32_t(cols));
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, std::uint32_t(rows));
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 32);
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
  TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_IEEEFP);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_NONE);
  TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, std::uint32_t(std::max(1, 65536 / (4 * cols))));
  TIFFSetField(tif, TIFFTAG_SUBFILETYPE, FILETYPE_PAGE);
  TIFFSetField(tif, TIFFTAG_PAGENUMBER, page, kPages);
  TIFFSetField(tif, TIFFTAG_PAGENAME, kPageNames[page]);
  if (!description.empty()) TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, description.c_str());
  for (int r = 0; r < rows; ++r)
    if (TIFFWriteScanline(tif, const_cast<float*>(data + std::size_t(r) * std::size_t(cols)),
                          std::uint32_t(r), 0) < 0)
      return io_error("cannot write the calibration's TIFF data (disk full?)");
  if (!TIFFWriteDirectory(tif)) return io_error("cannot write the calibration's TIFF directory (disk full?)");
  return {};
}

}  // namespace

Status read_page(TIFF* tif, int page, int rows, int cols, std::vector<float>* out, const std::string& where) {
  const std::string name = "page " + std::to_string(page + 1) + " (" + kPageNames[page] + ")";
  if (!TIFFSetDirectory(tif, tdir_t(page)))
    return corrupt_data(where + ": " + name + " is missing or unreadable");
  std::uint32_t w = 0, h = 0;
  std::uint16_t bits = 0, samples = 1, format = 0;
  TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &w);
  TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &h);
  TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &samples);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &format);
  if (w != std::uint32_t(cols) || h != std::uint32_t(rows))
    return corrupt_data(where + ": " + name + " is " + std::to_string(w) + " x " + std::to_string(h) +
                        " pixels, the metadata says " + std::to_string(cols) + " x " + std::to_string(rows));
  if (bits != 32 || samples != 1 || format != SAMPLEFORMAT_IEEEFP || TIFFIsTiled(tif))
    return corrupt_data(where + ": " + name + " is not one-sample 32-bit float in strips");
  if (std::uint64_t(TIFFScanlineSize64(tif)) != std::uint64_t(4) * std::uint64_t(cols))
    return corrupt_data(where + ": " + name + " has rows of an unexpected size");
  out->resize(std::size_t(rows) * std::size_t(cols));
  for (int r = 0; r < rows; ++r)
    if (TIFFReadScanline(tif, out->data() + std::size_t(r) * std::size_t(cols), std::uint32_t(r), 0) < 0)
      return corrupt_data(where + ": " + name + " is truncated or unreadable (row " + std::to_string(r + 1) +
                          ")");
  for (std::size_t i = 0; i < out->size(); ++i)
    if (!std::isfinite((*out)[i]))
      return corrupt_data(where + ": " + name + " holds a non-finite value at row " +
                          std::to_string(i / cols + 1) + ", column " + std::to_string(i % cols + 1));
  return {};
}

Status write_tiff(const fs::path& file, const calib::DetectorCalibration& c, const std::string& description) {
  TIFFSetWarningHandler(nullptr);
  TIFFSetErrorHandler(nullptr);
  TIFF* tif = TIFFOpen(file.c_str(), "w");
  if (tif == nullptr) return io_error("cannot create " + file.string() + ": " + std::strerror(errno));
  const std::size_t n = std::size_t(c.rows) * std::size_t(c.cols);
  std::vector<float> defects(n);
  for (std::size_t i = 0; i < n; ++i) defects[i] = c.defective.pixels()[i] ? 1.f : 0.f;
  const float* pages[kPages] = {c.offset_counts.pixels().data(), c.gain.pixels().data(),
                                c.noise_counts.pixels().data(), defects.data()};
  Status s;
  for (int p = 0; p < kPages && s.ok(); ++p)
    s = write_page(tif, pages[p], c.rows, c.cols, p == 0 ? description : "", p);
  if (s.ok() && !TIFFFlush(tif)) s = io_error("cannot write " + file.string() + " (disk full?)");
  if (s.ok() && ::fsync(TIFFFileno(tif)) != 0)
    s = io_error("cannot flush " + file.string() + ": " + std::strerror(errno));
  TIFFClose(tif);
  return s;
}

std::uint64_t last_directory_end(TIFF* tif, const fs::path& path) {
  if (!TIFFSetDirectory(tif, tdir_t(kPages - 1))) return 0;
  const std::uint64_t offset = TIFFCurrentDirOffset(tif);
  const bool big = TIFFIsBigTIFF(tif) != 0, swapped = TIFFIsByteSwapped(tif) != 0;
  const std::uint64_t count_size = big ? 8 : 2, entry_size = big ? 20 : 12, pointer_size = big ? 8 : 4;
  std::ifstream in(path, std::ios::binary);
  const auto read = [&](std::uint64_t at, std::uint64_t bytes, std::uint64_t* value) {
    unsigned char raw[8] = {};
    in.seekg(std::streamoff(at));
    if (!in.read(reinterpret_cast<char*>(raw), std::streamsize(bytes))) return false;
    *value = 0;
    for (std::uint64_t k = 0; k < bytes; ++k)
      *value |= std::uint64_t(raw[swapped ? bytes - 1 - k : k]) << (8 * k);
    return true;
  };
  std::uint64_t entries = 0;
  if (!read(offset, count_size, &entries) || entries > 4096) return 0;
  std::uint64_t end = offset + count_size + entries * entry_size + pointer_size;
  for (std::uint64_t e = 0; e < entries; ++e) {
    const std::uint64_t at = offset + count_size + e * entry_size;
    std::uint64_t type = 0, count = 0, value = 0;
    if (!read(at + 2, 2, &type) || !read(at + 4, pointer_size, &count)) return 0;
    static const std::uint64_t kTypeSize[19] = {0, 1, 1, 2, 4, 8, 1, 1, 2, 4, 8, 4, 8, 4, 0, 0, 8, 8, 8};
    const std::uint64_t bytes = count * (type < 19 ? kTypeSize[type] : 0);
    if (bytes <= pointer_size) continue;  // the value is in the entry
    if (!read(at + 4 + pointer_size, pointer_size, &value)) return 0;
    end = std::max(end, value + bytes);
  }
  return end;
}

}  // namespace lftrack::session::calibration_tiff
