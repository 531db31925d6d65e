#pragma once
// Detector frames as files: 16-bit greyscale TIFF or PNG, raw counts, the whole detector.
// The frame archive writes them and the replay source reads them (frame_sequence.hpp).
//
// Both functions work on caller-owned pixels and take plain C paths, so a reader or writer
// thread that prepared its paths and buffers beforehand makes no C++ heap allocation per frame
// (libtiff and libpng allocate with malloc internally; only an error builds a message).

#include <cstdint>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::drivers {

// Reads `path` (.tif/.tiff: one-sample 16-bit unsigned, strips, any libtiff compression;
// .png: 16-bit greyscale) into `out`, which has the detector's size. Errors:
// not_found (no such file), corrupt_data (not a readable image of that type, truncated),
// unsupported (another pixel format), out_of_range (a size other than `out`'s).
Status read_frame_file(const char* path, tracking::ImageView<std::uint16_t> out);

// The size of the frame in `path` (a .tif/.tiff or .png of the kinds read_frame_file reads),
// read from its header; a size beyond 16384 pixels a side is refused (a header that claims more
// than a detector has is not trusted with memory).
Status frame_file_size(const char* path, int* rows, int* cols);

// Writes `frame` as an uncompressed 16-bit TIFF (.tif/.tiff) or a 16-bit PNG (.png).
Status write_frame_file(const char* path, tracking::ImageView<const std::uint16_t> frame);

}  // namespace lftrack::drivers
