#pragma once
// Private to mutual information (mutual_information.cpp): the two per-pixel passes of a score,
// a row at a time, portable and in AVX2 lanes (the same results bit for bit: integer ranges,
// and float arithmetic without fused multiply-adds in both).

#include <cstddef>
#include <cstdint>

namespace lftrack::tracking {

// One row of the images. A pixel is usable when its fixed row offset is not `unusable_row`
// (fixed_row nullptr: every offset usable, for a range of one image alone), its moving mask
// (nullptr: all valid) is non-zero and its moving value is finite.
struct MiRow {
  const float* moving = nullptr;
  const unsigned char* moving_valid = nullptr;
  const std::uint32_t* fixed_row = nullptr;  // per pixel: fixed bin * bins, or unusable_row
  int cols = 0;
};

// How moving values become a cell and a weight: x = min((v - lo) * scale, top), j = min(int(x),
// last_bin), weight = min(int((x - j) * weight_unit + 0.5), weight_max); cell = fixed row offset
// + j. Unusable pixels get cell unusable_row + 0 and weight 0. weight_unit = weight_max = unit;
// top = last_bin + 1, the largest x of a range a float can hold, caps an x that overflowed.
struct MiBinning {
  std::uint32_t unusable_row = 0;
  float lo = 0, scale = 0, top = 1;
  int last_bin = 0;
  float weight_unit = 1;
  int weight_max = 1;
  std::uint32_t unit = 1;
};

// The sub-histograms' most copies: a score of more than kMiManyPixels pixels uses
// kMiSubHistograms of them, a smaller one a single histogram.
constexpr int kMiSubHistograms = 4;
constexpr int kMiManyPixels = 4096;

// `copies` sub-histograms (1 or kMiSubHistograms), interleaved: cell k of sub-histogram s is
// counts[k * copies + s], and pixel c of a row goes to sub-histogram c % copies. A cell is a pair
// of counts in one 64-bit word: the low half gets the pixel's lower bin's share (unit - weight),
// the high half its upper bin's (weight), so that a pixel is one read-add-write.
// Interleaved, the sub-histograms' copies of a cell share a cache line: neighbouring pixels, which
// often fall in the same cell, write different words of one line, and the lines a score touches
// are a quarter of those of four separate histograms (133 KB at 64 bins, beyond the L1 cache).
// A small image's score is set by clearing, summing and scanning the cells, not by its pixels'
// waits on each other: one copy (33 KB at 64 bins) is then faster.
struct MiHistograms {
  std::uint64_t* counts = nullptr;
  int copies = kMiSubHistograms;
};

// A float's bits as an integer of the same order (negative floats reversed): the moving range
// is an integer min / max.
inline std::int32_t mi_order_key(float v) {
  const std::int32_t bits = __builtin_bit_cast(std::int32_t, v);
  return bits ^ ((bits >> 31) & 0x7fffffff);
}
inline float mi_from_order_key(std::int32_t key) {
  return __builtin_bit_cast(float, key ^ ((key >> 31) & 0x7fffffff));
}

// True if this CPU runs the AVX2 passes.
bool mi_avx2_available();

// The usable pixels' moving range (order keys, folded into *lo_key / *hi_key); returns their number.
int mi_moving_range(const MiRow& row, std::uint32_t unusable_row, std::int32_t* lo_key, std::int32_t* hi_key,
                    bool avx2);
// Adds each pixel's cell pair into the sub-histograms.
void mi_accumulate(const MiRow& row, const MiBinning& b, const MiHistograms& h, bool avx2);

// The fixed image's rows of the joint histogram: out[c] = row_stride * clamp(int((in[c] - lo) *
// scale), 0, last_bin) for the usable pixels of a row (finite, and mask nullptr or non-zero),
// unusable_row for the others; a product past last_bin (inf included) gets last_bin. The same
// arithmetic (a float difference, a double product) portable and in AVX2 lanes.
void mi_fixed_rows(const float* in, const unsigned char* valid, int cols, float lo, double scale, int last_bin,
                   std::uint32_t row_stride, std::uint32_t unusable_row, std::uint32_t* out, bool avx2);

}  // namespace lftrack::tracking
