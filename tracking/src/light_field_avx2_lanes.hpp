#pragma once
// Private to the AVX2 light-field kernels (light_field_kernel_avx2.cpp, the per-ray blend, and
// light_field_source_image_avx2.cpp, the source image): a storage mode's access to samples in
// lanes, the blends, the runs of samples and a row's rays in lanes. Everything here is compiled
// for AVX2 + FMA through function target attributes and is only called once
// light_field_avx2_available() holds; an x86-64 GCC or Clang build only.

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>

#include "light_field_kernels.hpp"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>

namespace lftrack::tracking {
namespace {

#define LFTRACK_AVX2 __attribute__((target("avx2,fma")))

// A storage mode's access to the samples, as floats before `finish`:
//   pairs(idx, first, second): the gather path, the samples at idx and idx + 1 (t neighbours)
//   load8(offset):             the eight consecutive samples from offset
//   finish(value):             the interpolated value in mu * mm

// Float samples: pairs fetched as 8-byte elements, two gathers of four instead of two of eight.
// The indices go in as pixels (0,1,4,5) and (2,3,6,7) so that the unpacking shuffles give pixel
// order back.
struct FloatSamples {
  const float* f;
  LFTRACK_AVX2 inline void pairs(__m256i idx, __m256* first, __m256* second) const {
    const __m256i order = _mm256_setr_epi32(0, 1, 4, 5, 2, 3, 6, 7);
    const __m256i p = _mm256_permutevar8x32_epi32(idx, order);
    const double* base = reinterpret_cast<const double*>(f);
    // The masked form with an explicit zero source (GCC 12 flags the plain form's undefined one).
    const __m256d zero = _mm256_setzero_pd();
    const __m256d all = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
    const __m256 x = _mm256_castpd_ps(_mm256_mask_i32gather_pd(zero, base, _mm256_castsi256_si128(p), all, 4));
    const __m256 y =
        _mm256_castpd_ps(_mm256_mask_i32gather_pd(zero, base, _mm256_extracti128_si256(p, 1), all, 4));
    *first = _mm256_shuffle_ps(x, y, _MM_SHUFFLE(2, 0, 2, 0));
    *second = _mm256_shuffle_ps(x, y, _MM_SHUFFLE(3, 1, 3, 1));
  }
  LFTRACK_AVX2 inline __m256 load8(std::size_t offset) const { return _mm256_loadu_ps(f + offset); }
  LFTRACK_AVX2 inline __m256 finish(__m256 value) const { return value; }
};

// 16-bit samples (value = code * scale): one gather of eight 4-byte words at idx reads both
// q[idx] and q[idx + 1] (idx + 1 is always inside the field: t is clamped to size - 2).
struct Fixed16Samples {
  const std::uint16_t* q;
  float scale;
  LFTRACK_AVX2 inline void pairs(__m256i idx, __m256* first, __m256* second) const {
    const __m256i words = _mm256_mask_i32gather_epi32(_mm256_setzero_si256(), reinterpret_cast<const int*>(q),
                                                      idx, _mm256_set1_epi32(-1), 2);
    *first = _mm256_cvtepi32_ps(_mm256_and_si256(words, _mm256_set1_epi32(0xffff)));
    *second = _mm256_cvtepi32_ps(_mm256_srli_epi32(words, 16));
  }
  LFTRACK_AVX2 inline __m256 load8(std::size_t offset) const {
    const __m128i codes = _mm_loadu_si128(reinterpret_cast<const __m128i*>(q + offset));
    return _mm256_cvtepi32_ps(_mm256_cvtepu16_epi32(codes));
  }
  LFTRACK_AVX2 inline __m256 finish(__m256 value) const { return _mm256_mul_ps(value, _mm256_set1_ps(scale)); }
};

// Bilinear blend in (s, t) of a top pair (a, b) and a bottom pair (c, d).
LFTRACK_AVX2 inline __m256 blend_st(__m256 a, __m256 b, __m256 c, __m256 d, __m256 ws, __m256 wt) {
  const __m256 top = _mm256_fmadd_ps(wt, _mm256_sub_ps(b, a), a);
  const __m256 bottom = _mm256_fmadd_ps(wt, _mm256_sub_ps(d, c), c);
  return _mm256_fmadd_ps(ws, _mm256_sub_ps(bottom, top), top);
}

// The gather path: (u, v) cell at idx (its (s, t) corner), blended in (s, t).
template <class Samples>
LFTRACK_AVX2 inline __m256 gathered_cell(const Samples& f, __m256i idx, __m256i stride_s, __m256 ws, __m256 wt) {
  __m256 a, b, c, d;
  f.pairs(idx, &a, &b);
  f.pairs(_mm256_add_epi32(idx, stride_s), &c, &d);
  return blend_st(a, b, c, d, ws, wt);
}

// One run of samples of a (u, v, s) row, from t0, and each lane's pair (dt, dt + 1) from it.
// Narrow runs: dt + 1 < 8, one register. Wide runs: dt + 1 < 16, two registers.
template <class Samples, bool kWide>
LFTRACK_AVX2 inline void run_pairs(const Samples& f, std::size_t offset, __m256i dt, __m256i dt_next,
                                   __m256 upper_first, __m256 upper_second, __m256* first, __m256* second) {
  const __m256 lo = f.load8(offset);
  if constexpr (!kWide) {
    *first = _mm256_permutevar8x32_ps(lo, dt);
    *second = _mm256_permutevar8x32_ps(lo, dt_next);
  } else {
    // vpermps reads the low three index bits; the lane's fourth bit picks the register.
    const __m256 hi = f.load8(offset + 8);
    *first = _mm256_blendv_ps(_mm256_permutevar8x32_ps(lo, dt), _mm256_permutevar8x32_ps(hi, dt), upper_first);
    *second =
        _mm256_blendv_ps(_mm256_permutevar8x32_ps(lo, dt_next), _mm256_permutevar8x32_ps(hi, dt_next), upper_second);
  }
}

// The chunk's lanes in the runs of one s row range: each lane's offset dt from t0, which of
// two registers holds dt and dt + 1 (wide runs), and whether its top row is below s0 + 1 and
// s0 + 2.
struct RunLanes {
  __m256i dt, dt_next;
  __m256 upper_first, upper_second;
  __m256 below1, below2;
};

// One (u, v) cell of a chunk that qualifies for runs, blended in (s, t): rows s0 .. s0 + s_span
// + 1 of the cell from `cell` (its row s0 at t0); each lane's top row is is - s0 of them and its
// bottom row the next. (No arrays: GCC clears or spills arrays of vectors.)
template <class Samples, bool kWide>
LFTRACK_AVX2 inline __m256 run_cell(const Samples& f, std::size_t cell, std::size_t nt, int s_span, const RunLanes& l,
                                    __m256 ws, __m256 wt) {
  __m256 a0, b0, a1, b1;
  run_pairs<Samples, kWide>(f, cell, l.dt, l.dt_next, l.upper_first, l.upper_second, &a0, &b0);
  run_pairs<Samples, kWide>(f, cell + nt, l.dt, l.dt_next, l.upper_first, l.upper_second, &a1, &b1);
  if (s_span == 0) return blend_st(a0, b0, a1, b1, ws, wt);
  __m256 a2, b2;
  run_pairs<Samples, kWide>(f, cell + 2 * nt, l.dt, l.dt_next, l.upper_first, l.upper_second, &a2, &b2);
  __m256 a = _mm256_blendv_ps(a0, a1, l.below1), b = _mm256_blendv_ps(b0, b1, l.below1);
  __m256 c = _mm256_blendv_ps(a1, a2, l.below1), d = _mm256_blendv_ps(b1, b2, l.below1);
  if (s_span == 2) {
    __m256 a3, b3;
    run_pairs<Samples, kWide>(f, cell + 3 * nt, l.dt, l.dt_next, l.upper_first, l.upper_second, &a3, &b3);
    a = _mm256_blendv_ps(a, a2, l.below2);
    b = _mm256_blendv_ps(b, b2, l.below2);
    c = _mm256_blendv_ps(c, a3, l.below2);
    d = _mm256_blendv_ps(d, b3, l.below2);
  }
  return blend_st(a, b, c, d, ws, wt);
}

LFTRACK_AVX2 inline int first_lane(__m256i v) { return _mm_cvtsi128_si32(_mm256_castsi256_si128(v)); }
LFTRACK_AVX2 inline int last_lane(__m256i v) { return _mm256_extract_epi32(v, 7); }

// Eight mask bits as eight bytes of 0 or 1 (bit k to byte k, little-endian).
struct MaskBytes {
  std::uint64_t bytes[256];
  constexpr MaskBytes() : bytes() {
    for (int bits = 0; bits < 256; ++bits)
      for (int k = 0; k < 8; ++k)
        if ((bits >> k) & 1) bytes[bits] |= std::uint64_t{1} << (8 * k);
  }
};
constexpr MaskBytes kMaskBytes;

// A row's ray directions: d.n, d.e1 and d.e2 are affine in the column. inside: every ray of the
// row passes the field test (row_inside_field, the caller's), so its chunks of eight skip it.
struct RowRays {
  __m256 dn0, dn1, de10, de11, de20, de21;
  bool inside;
};

LFTRACK_AVX2 inline RowRays row_rays(const LightFieldGeometry& g, const RayMap& m, int r, bool inside) {
  const Eigen::Vector3d d_row = m.d00 + m.d_row * r;
  return {_mm256_set1_ps(float(d_row.dot(g.axis))), _mm256_set1_ps(float(m.d_col.dot(g.axis))),
          _mm256_set1_ps(float(d_row.dot(g.e1))),   _mm256_set1_ps(float(m.d_col.dot(g.e1))),
          _mm256_set1_ps(float(d_row.dot(g.e2))),   _mm256_set1_ps(float(m.d_col.dot(g.e2))),
          inside};
}

// The ray map's constants in lanes.
struct MapLanes {
  __m256 base[4], gain[4], limit[4];
  explicit LFTRACK_AVX2 MapLanes(const RayMap& m) {
    for (int a = 0; a < 4; ++a) {
      base[a] = _mm256_set1_ps(m.base[a]);
      gain[a] = _mm256_set1_ps(m.gain[a]);
      limit[a] = _mm256_set1_ps(m.limit[a]);
    }
  }
};

// Eight pixels' rays from column c: their sample coordinates (u, v, s, t), 0 in lanes outside
// the field or past the row's end, which lanes are inside, and how many lanes the row has left.
struct ChunkRays {
  __m256 cu, cv, cs, ct, inside;
  int inside_bits, lanes;
};

LFTRACK_AVX2 inline ChunkRays chunk_rays(const RowRays& row, const MapLanes& map, int c, int cols) {
  const __m256 zero = _mm256_setzero_ps();
  const __m256 lanes8 = _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256 cf = _mm256_add_ps(_mm256_set1_ps(float(c)), lanes8);
  const __m256 dn = _mm256_fmadd_ps(row.dn1, cf, row.dn0);
  const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), dn);
  const __m256 q1 = _mm256_mul_ps(_mm256_fmadd_ps(row.de11, cf, row.de10), inv);
  const __m256 q2 = _mm256_mul_ps(_mm256_fmadd_ps(row.de21, cf, row.de20), inv);
  const __m256 fu = _mm256_fmadd_ps(map.gain[0], q1, map.base[0]), fv = _mm256_fmadd_ps(map.gain[1], q2, map.base[1]);
  const __m256 fs = _mm256_fmadd_ps(map.gain[2], q1, map.base[2]), ft = _mm256_fmadd_ps(map.gain[3], q2, map.base[3]);
  // A whole chunk of a row whose rays are all inside: the test below would pass in every lane.
  if (row.inside && cols - c >= 8) return {fu, fv, fs, ft, _mm256_castsi256_ps(_mm256_set1_epi32(-1)), 0xff, 8};
  // Ordered comparisons: NaN is outside.
  __m256 inside = _mm256_cmp_ps(dn, zero, _CMP_GT_OQ);
  inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(fu, zero, _CMP_GE_OQ), _mm256_cmp_ps(fu, map.limit[0], _CMP_LE_OQ)));
  inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(fv, zero, _CMP_GE_OQ), _mm256_cmp_ps(fv, map.limit[1], _CMP_LE_OQ)));
  inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(fs, zero, _CMP_GE_OQ), _mm256_cmp_ps(fs, map.limit[2], _CMP_LE_OQ)));
  inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(ft, zero, _CMP_GE_OQ), _mm256_cmp_ps(ft, map.limit[3], _CMP_LE_OQ)));
  // Lanes past the row's end are outside too.
  const int lanes = cols - c < 8 ? cols - c : 8;
  inside = _mm256_and_ps(inside, _mm256_cmp_ps(lanes8, _mm256_set1_ps(float(lanes)), _CMP_LT_OQ));
  return {_mm256_and_ps(fu, inside), _mm256_and_ps(fv, inside), _mm256_and_ps(fs, inside), _mm256_and_ps(ft, inside),
          inside, _mm256_movemask_ps(inside), lanes};
}

// Stores a chunk's values (0 outside) and, with a mask row, its inside flags.
LFTRACK_AVX2 inline void store_chunk(const ChunkRays& k, __m256 value, float* dst, unsigned char* ok_row) {
  value = _mm256_and_ps(value, k.inside);
  if (k.lanes == 8) {
    _mm256_storeu_ps(dst, value);
  } else {
    alignas(32) float tail[8];
    _mm256_store_ps(tail, value);
    for (int i = 0; i < k.lanes; ++i) dst[i] = tail[i];
  }
  if (ok_row) {
    const std::uint64_t flags = kMaskBytes.bytes[k.inside_bits];
    if (k.lanes == 8)
      std::memcpy(ok_row, &flags, 8);
    else
      for (int i = 0; i < k.lanes; ++i) ok_row[i] = static_cast<unsigned char>((k.inside_bits >> i) & 1);
  }
}

// Where a chunk's (s, t) indices lie in runs: t within 15 samples and s within three rows from
// (s0, t0). Lanes 0 and 7 give the range (t and s are monotonic along a row); every lane is then
// checked against it, since rounding may bend monotonicity by a sample where the coordinates
// barely change. `other` holds nonzero lanes where a caller's own test fails.
struct RunRange {
  int s0, t0, s_span, t_span;
  bool ok;
};

LFTRACK_AVX2 inline RunRange run_range(__m256i is, __m256i it, __m256i other) {
  const int t_first = first_lane(it), t_last = last_lane(it);
  const int s_first = first_lane(is), s_last = last_lane(is);
  RunRange r;
  r.t0 = std::min(t_first, t_last);
  r.s0 = std::min(s_first, s_last);
  r.t_span = std::max(t_first, t_last) - r.t0;
  r.s_span = std::max(s_first, s_last) - r.s0;
  const __m256i vt0 = _mm256_set1_epi32(r.t0), vs0 = _mm256_set1_epi32(r.s0);
  const __m256i outside = _mm256_or_si256(
      other, _mm256_or_si256(
                 _mm256_or_si256(_mm256_cmpgt_epi32(vt0, it), _mm256_cmpgt_epi32(it, _mm256_set1_epi32(r.t0 + r.t_span))),
                 _mm256_or_si256(_mm256_cmpgt_epi32(vs0, is), _mm256_cmpgt_epi32(is, _mm256_set1_epi32(r.s0 + r.s_span)))));
  r.ok = _mm256_testz_si256(outside, outside) && r.t_span <= 14 && r.s_span <= 2;
  return r;
}

LFTRACK_AVX2 inline RunLanes run_lanes(__m256i is, __m256i it, const RunRange& r) {
  RunLanes l;
  const __m256i vs0 = _mm256_set1_epi32(r.s0);
  l.dt = _mm256_sub_epi32(it, _mm256_set1_epi32(r.t0));
  l.dt_next = _mm256_add_epi32(l.dt, _mm256_set1_epi32(1));
  l.upper_first = _mm256_castsi256_ps(_mm256_cmpgt_epi32(l.dt, _mm256_set1_epi32(7)));
  l.upper_second = _mm256_castsi256_ps(_mm256_cmpgt_epi32(l.dt_next, _mm256_set1_epi32(7)));
  l.below1 = _mm256_castsi256_ps(_mm256_cmpgt_epi32(is, vs0));
  l.below2 = _mm256_castsi256_ps(_mm256_cmpgt_epi32(is, _mm256_set1_epi32(r.s0 + 1)));
  return l;
}

}  // namespace
}  // namespace lftrack::tracking

#endif
