#pragma once
// Small image files whose headers claim far more pixels than they hold (an outsider's bad input:
// a 65535 x 65535 TIFF of a few hundred bytes, a 100000 x 100000 PNG of 57 bytes). Readers must
// refuse them before allocating. The test binaries that include this link TIFF and ZLIB.

#include <tiffio.h>
#include <zlib.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace lftrack::test {

// A 16-bit greyscale TIFF (uncompressed, or deflate when `compressed`) whose tags claim
// cols x rows pixels; one row of data is written.
inline bool write_lying_tiff(const std::filesystem::path& file, std::uint32_t cols, std::uint32_t rows,
                             bool compressed = false) {
  TIFFSetWarningHandler(nullptr);
  TIFFSetErrorHandler(nullptr);
  TIFF* tif = TIFFOpen(file.c_str(), "w");
  if (tif == nullptr) return false;
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, cols);
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, rows);
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 16);
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
  TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_UINT);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, rows);  // one strip: the file stays small
  TIFFSetField(tif, TIFFTAG_COMPRESSION, compressed ? COMPRESSION_ADOBE_DEFLATE : COMPRESSION_NONE);
  std::vector<std::uint16_t> row(cols, 1000);
  const bool ok = TIFFWriteScanline(tif, row.data(), 0, 0) >= 0;
  TIFFClose(tif);
  return ok;
}

// A PNG of the signature, an IHDR claiming cols x rows 16-bit grey pixels, one IDAT of a few
// bytes (a first row's start) and IEND.
inline bool write_lying_png(const std::filesystem::path& file, std::uint32_t cols, std::uint32_t rows) {
  auto be32 = [](std::string* out, std::uint32_t v) {
    for (int shift = 24; shift >= 0; shift -= 8) out->push_back(static_cast<char>((v >> shift) & 0xff));
  };
  auto chunk = [&](std::string* out, const char* type, const std::string& data) {
    be32(out, static_cast<std::uint32_t>(data.size()));
    const std::string body = std::string(type, 4) + data;
    out->append(body);
    be32(out, static_cast<std::uint32_t>(
                  crc32(0, reinterpret_cast<const Bytef*>(body.data()), static_cast<uInt>(body.size()))));
  };
  std::string png("\x89PNG\r\n\x1a\n", 8);
  std::string ihdr;
  be32(&ihdr, cols);
  be32(&ihdr, rows);
  ihdr += std::string("\x10\x00\x00\x00\x00", 5);  // 16 bits, grey, deflate, adaptive, no interlace
  chunk(&png, "IHDR", ihdr);
  const std::string row(64, '\0');
  std::vector<Bytef> deflated(compressBound(uLong(row.size())));
  uLongf deflated_size = uLongf(deflated.size());
  if (compress(deflated.data(), &deflated_size, reinterpret_cast<const Bytef*>(row.data()), uLong(row.size())) != Z_OK)
    return false;
  chunk(&png, "IDAT", std::string(reinterpret_cast<const char*>(deflated.data()), deflated_size));
  chunk(&png, "IEND", "");
  std::ofstream out(file, std::ios::binary);
  out.write(png.data(), static_cast<std::streamsize>(png.size()));
  return bool(out);
}

}  // namespace lftrack::test
