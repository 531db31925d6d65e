// The per-pixel passes of mutual information (mutual_information_kernels.hpp): portable loops,
// and the same in eight AVX2 lanes, compiled through function target attributes and chosen at
// run time (GCC 12 does not vectorise the portable loops: it turns the masks into branches).

#include "mutual_information_kernels.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

namespace lftrack::tracking {
namespace {

// A value finite (false for NaN and inf) and its mask (nullptr: all valid) non-zero.
inline bool finite_and_valid(const float* values, const unsigned char* valid, int c) {
  return (valid == nullptr || valid[c] != 0) & (std::abs(values[c]) <= std::numeric_limits<float>::max());
}

inline bool usable_pixel(const MiRow& row, std::uint32_t unusable_row, int c) {
  return (row.fixed_row == nullptr || row.fixed_row[c] != unusable_row) & finite_and_valid(row.moving, row.moving_valid, c);
}

int range_scalar(const MiRow& row, std::uint32_t unusable_row, int c0, std::int32_t* lo_key, std::int32_t* hi_key) {
  int n = 0;
  for (int c = c0; c < row.cols; ++c) {
    if (!usable_pixel(row, unusable_row, c)) continue;
    const std::int32_t key = mi_order_key(row.moving[c]);
    *lo_key = std::min(*lo_key, key);
    *hi_key = std::max(*hi_key, key);
    ++n;
  }
  return n;
}

// Pixel c's cell pair: the lower bin's share in the low half, the upper bin's in the high half.
inline std::uint64_t cell_pair(std::uint32_t weight, std::uint32_t unit) {
  return (std::uint64_t{weight} << 32) | (unit - weight);
}

void accumulate_scalar(const MiRow& row, const MiBinning& b, int c0, const MiHistograms& h) {
  const std::size_t lane_mask = std::size_t(h.copies - 1);  // copies is a power of two
  for (int c = c0; c < row.cols; ++c) {
    const bool ok = usable_pixel(row, b.unusable_row, c);
    // >= 0 for usable pixels; at most last_bin + 1, also where the range is beyond a float's (inf).
    const float product = ok ? (row.moving[c] - b.lo) * b.scale : 0.0f;
    const float x = product < b.top ? product : b.top;
    const int j = std::min(static_cast<int>(x), b.last_bin);
    const float rounded = (x - float(j)) * b.weight_unit + 0.5f;
    const int w = std::min(static_cast<int>(rounded), b.weight_max);
    const std::uint32_t cell = (ok ? row.fixed_row[c] : b.unusable_row) + std::uint32_t(j);
    h.counts[std::size_t(cell) * std::size_t(h.copies) + (std::size_t(c) & lane_mask)] +=
        cell_pair(std::uint32_t(ok ? w : 0), b.unit);
  }
}

void fixed_rows_scalar(const float* in, const unsigned char* valid, int c0, int cols, float lo, double scale,
                       int last_bin, std::uint32_t row_stride, std::uint32_t unusable_row, std::uint32_t* out) {
  for (int c = c0; c < cols; ++c) {
    const bool ok = finite_and_valid(in, valid, c);
    const float x = ok ? in[c] : lo;
    // Capped before the conversion: a difference past the float range (inf) gets the last bin.
    const double t = double(x - lo) * scale;
    const int bin = std::max(static_cast<int>(t < double(last_bin) ? t : double(last_bin)), 0);
    out[c] = ok ? std::uint32_t(bin) * row_stride : unusable_row;
  }
}

#if defined(__x86_64__) && defined(__GNUC__)

#define LFTRACK_AVX2 __attribute__((target("avx2")))

// All-ones in the lanes of values c .. c + 7 that are finite and whose mask (nullptr: all valid)
// is non-zero, within `ok`.
LFTRACK_AVX2 inline __m256i finite_and_valid_lanes(const float* values, const unsigned char* valid, int c, __m256i ok) {
  if (valid != nullptr) {
    const __m128i bytes = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(valid + c));
    const __m256i mask = _mm256_cvtepu8_epi32(bytes);
    ok = _mm256_andnot_si256(_mm256_cmpeq_epi32(mask, _mm256_setzero_si256()), ok);
  }
  // Finite: |bits| at most the largest float's.
  const __m256i magnitude =
      _mm256_and_si256(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(values + c)), _mm256_set1_epi32(0x7fffffff));
  return _mm256_andnot_si256(_mm256_cmpgt_epi32(magnitude, _mm256_set1_epi32(0x7f7fffff)), ok);
}

// All-ones in the lanes of pixels c .. c + 7 that are usable.
LFTRACK_AVX2 inline __m256i usable_lanes(const MiRow& row, __m256i unusable, int c) {
  __m256i ok = _mm256_set1_epi32(-1);
  if (row.fixed_row != nullptr) {
    const __m256i fixed = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(row.fixed_row + c));
    ok = _mm256_xor_si256(_mm256_cmpeq_epi32(fixed, unusable), ok);
  }
  return finite_and_valid_lanes(row.moving, row.moving_valid, c, ok);
}

LFTRACK_AVX2 int range_avx2(const MiRow& row, std::uint32_t unusable_row, std::int32_t* lo_key,
                            std::int32_t* hi_key) {
  const __m256i unusable = _mm256_set1_epi32(int(unusable_row));
  const __m256i top = _mm256_set1_epi32(std::numeric_limits<std::int32_t>::max());
  const __m256i bottom = _mm256_set1_epi32(std::numeric_limits<std::int32_t>::min());
  __m256i lo = top, hi = bottom;
  int n = 0, c = 0;
  for (; c + 8 <= row.cols; c += 8) {
    const __m256i ok = usable_lanes(row, unusable, c);
    const __m256i bits = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(row.moving + c));
    const __m256i key = _mm256_xor_si256(bits, _mm256_and_si256(_mm256_srai_epi32(bits, 31), _mm256_set1_epi32(0x7fffffff)));
    lo = _mm256_min_epi32(lo, _mm256_blendv_epi8(top, key, ok));
    hi = _mm256_max_epi32(hi, _mm256_blendv_epi8(bottom, key, ok));
    n += __builtin_popcount(static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(ok))));
  }
  alignas(32) std::int32_t l[8], h[8];
  _mm256_store_si256(reinterpret_cast<__m256i*>(l), lo);
  _mm256_store_si256(reinterpret_cast<__m256i*>(h), hi);
  for (int k = 0; k < 8; ++k) {
    *lo_key = std::min(*lo_key, l[k]);
    *hi_key = std::max(*hi_key, h[k]);
  }
  return n + range_scalar(row, unusable_row, c, lo_key, hi_key);
}

// Copies: the number of sub-histograms, a constant in each instance (lane k goes to k % Copies).
template <int Copies>
LFTRACK_AVX2 void accumulate_avx2(const MiRow& row, const MiBinning& b, const MiHistograms& h) {
  const __m256i unusable = _mm256_set1_epi32(int(b.unusable_row));
  const __m256 lo = _mm256_set1_ps(b.lo), scale = _mm256_set1_ps(b.scale);
  const __m256 unit = _mm256_set1_ps(b.weight_unit), half = _mm256_set1_ps(0.5f), top = _mm256_set1_ps(b.top);
  const __m256i last = _mm256_set1_epi32(b.last_bin), wmax = _mm256_set1_epi32(b.weight_max);
  int c = 0;
  for (; c + 8 <= row.cols; c += 8) {
    const __m256i ok = usable_lanes(row, unusable, c);
    const __m256 v = _mm256_loadu_ps(row.moving + c);
    const __m256 x =
        _mm256_min_ps(_mm256_and_ps(_mm256_mul_ps(_mm256_sub_ps(v, lo), scale), _mm256_castsi256_ps(ok)), top);
    const __m256i j = _mm256_min_epi32(_mm256_cvttps_epi32(x), last);
    const __m256 rounded = _mm256_add_ps(_mm256_mul_ps(_mm256_sub_ps(x, _mm256_cvtepi32_ps(j)), unit), half);
    const __m256i w = _mm256_and_si256(_mm256_min_epi32(_mm256_cvttps_epi32(rounded), wmax), ok);
    const __m256i fixed = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(row.fixed_row + c));
    alignas(32) std::uint32_t cell[8], weight[8];
    _mm256_store_si256(reinterpret_cast<__m256i*>(cell), _mm256_add_epi32(_mm256_blendv_epi8(unusable, fixed, ok), j));
    _mm256_store_si256(reinterpret_cast<__m256i*>(weight), w);
    // Lane k to sub-histogram k % Copies, as the portable loop (c is a multiple of 8).
    static_assert(8 % Copies == 0);
    for (int k = 0; k < 8; ++k)
      h.counts[std::size_t(cell[k]) * Copies + std::size_t(k % Copies)] += cell_pair(weight[k], b.unit);
  }
  accumulate_scalar(row, b, c, h);
}

LFTRACK_AVX2 void fixed_rows_avx2(const float* in, const unsigned char* valid, int cols, float lo, double scale,
                                   int last_bin, std::uint32_t row_stride, std::uint32_t unusable_row,
                                   std::uint32_t* out) {
  const __m256 lo8 = _mm256_set1_ps(lo);
  const __m256d scale4 = _mm256_set1_pd(scale), last4 = _mm256_set1_pd(double(last_bin));
  const __m256i stride = _mm256_set1_epi32(int(row_stride)), unusable = _mm256_set1_epi32(int(unusable_row));
  int c = 0;
  for (; c + 8 <= cols; c += 8) {
    const __m256i ok = finite_and_valid_lanes(in, valid, c, _mm256_set1_epi32(-1));
    const __m256 d = _mm256_sub_ps(_mm256_blendv_ps(lo8, _mm256_loadu_ps(in + c), _mm256_castsi256_ps(ok)), lo8);
    // min_pd(t, last) is last where t is NaN, as the portable loop's t < last ? t : last.
    const __m128i low = _mm256_cvttpd_epi32(_mm256_min_pd(_mm256_mul_pd(_mm256_cvtps_pd(_mm256_castps256_ps128(d)), scale4), last4));
    const __m128i high = _mm256_cvttpd_epi32(_mm256_min_pd(_mm256_mul_pd(_mm256_cvtps_pd(_mm256_extractf128_ps(d, 1)), scale4), last4));
    const __m256i bin = _mm256_max_epi32(_mm256_set_m128i(high, low), _mm256_setzero_si256());
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + c),
                        _mm256_blendv_epi8(unusable, _mm256_mullo_epi32(bin, stride), ok));
  }
  fixed_rows_scalar(in, valid, c, cols, lo, scale, last_bin, row_stride, unusable_row, out);
}

#endif

}  // namespace

int mi_moving_range(const MiRow& row, std::uint32_t unusable_row, std::int32_t* lo_key, std::int32_t* hi_key,
                    bool avx2) {
#if defined(__x86_64__) && defined(__GNUC__)
  if (avx2) return range_avx2(row, unusable_row, lo_key, hi_key);
#endif
  (void)avx2;
  return range_scalar(row, unusable_row, 0, lo_key, hi_key);
}

void mi_accumulate(const MiRow& row, const MiBinning& b, const MiHistograms& h, bool avx2) {
#if defined(__x86_64__) && defined(__GNUC__)
  if (avx2 && h.copies == kMiSubHistograms) return accumulate_avx2<kMiSubHistograms>(row, b, h);
  if (avx2 && h.copies == 1) return accumulate_avx2<1>(row, b, h);
#endif
  (void)avx2;
  accumulate_scalar(row, b, 0, h);
}

void mi_fixed_rows(const float* in, const unsigned char* valid, int cols, float lo, double scale, int last_bin,
                   std::uint32_t row_stride, std::uint32_t unusable_row, std::uint32_t* out, bool avx2) {
#if defined(__x86_64__) && defined(__GNUC__)
  if (avx2) return fixed_rows_avx2(in, valid, cols, lo, scale, last_bin, row_stride, unusable_row, out);
#endif
  (void)avx2;
  fixed_rows_scalar(in, valid, 0, cols, lo, scale, last_bin, row_stride, unusable_row, out);
}

}  // namespace lftrack::tracking
