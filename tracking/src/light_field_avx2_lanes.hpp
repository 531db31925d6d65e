#pragma once
// Private to the AVX2 light-field kernels (light_field_kernel_avx2.cpp, the per-ray blend, and
// light_field_source_image_avx2.cpp, the source image): what both use, the (s, t) blend, a row's
// rays and a chunk's in lanes, and the chunk's store with its mask. Everything here is compiled
// for AVX2 + FMA through function target attributes and is only called once
// light_field_avx2_available() holds; an x86-64 GCC or Clang build only.

#include <cstddef>
#include <cstdint>
#include <cstring>

#include "light_field_kernels.hpp"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>

namespace lftrack::tracking {
namespace {

#define LFTRACK_AVX2 __attribute__((target("avx2,fma")))

// Bilinear blend in (s, t) of a top pair (a, b) and a bottom pair (c, d).
LFTRACK_AVX2 inline __m256 blend_st(__m256 a, __m256 b, __m256 c, __m256 d, __m256 ws, __m256 wt) {
  const __m256 top = _mm256_fmadd_ps(wt, _mm256_sub_ps(b, a), a);
  const __m256 bottom = _mm256_fmadd_ps(wt, _mm256_sub_ps(d, c), c);
  return _mm256_fmadd_ps(ws, _mm256_sub_ps(bottom, top), top);
}

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

}  // namespace
}  // namespace lftrack::tracking

#endif
