#pragma once
// 8-bit grey images for the monitor page (cycle_hub.hpp): values windowed between their 1st and
// 99th percentiles and binned down to a size a browser draws at once. Hub thread only.

#include <cstdint>

#include "lftrack/tracking/image.hpp"
#include "lftrack/watch/cycle_hub.hpp"

namespace lftrack::watch {

// `values` averaged over bin x bin blocks (only pixels marked in `valid`, when it is given) and
// windowed to 0..255; a block with no valid pixel is 0. Non-finite values count as invalid.
GreyImage windowed_grey(tracking::ImageView<const float> values, tracking::ImageView<const unsigned char> valid,
                        int bin);

// Raw detector counts on a log scale, attenuation bright (-ln of the count, windowed), binned
// so the longer side is at most `max_side`; *bin says by how much. Pixels of 0 counts (not read
// out, or dead) are left out; a block of only those is black.
GreyImage raw_thumbnail(const tracking::Image<std::uint16_t>& raw, int max_side, int* bin);

// The bin that brings the longer of rows and cols to at most max_side.
int bin_for(int rows, int cols, int max_side);

}  // namespace lftrack::watch
