// The AVX-512 light-field kernels: sixteen pixels of a row per iteration and, for float and
// 16-bit fields, wherever possible no gathers at all.
//
// Why that is possible: across a DRR the (u, v) coordinates of the pixels' rays barely move (all
// rays leave one source, and the (u, v) plane passes through the nominal source), while (s, t)
// follow the detector. Sixteen neighbouring pixels of a row therefore usually share their four
// (u, v) cells, their t indices rise or fall monotonically over fewer than 31 samples (a row's
// ray coordinates are a linear-fractional, hence monotonic, function of the column; t runs along
// the detector's rows, see light_field.hpp) and their s indices span at most three values. Then
// each (u, v) cell's samples for all sixteen pixels lie in two to four runs of 32 consecutive
// samples of the field, one per s row: the kernel loads those runs and hands each pixel its pair
// (t, t + 1) with one in-register permutation (vpermw for 16-bit samples, vpermt2ps for float)
// instead of the AVX2 kernel's 8 gathers. Chunks that do not qualify (at the field's edges,
// out-of-field pixels, a row's tail, a (u, v) cell boundary) take a gather path with the same
// arithmetic. VQ fields always gather (a code, then a codeword element, per sample).
//
// The results equal the scalar kernel's up to float rounding (fused multiply-adds). Compiled
// for AVX-512F and BW through function target attributes and chosen at run time, so the binary
// still runs on any x86-64 CPU.

#include <algorithm>
#include <cstddef>

#include "light_field_kernels.hpp"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

namespace lftrack::tracking {

#if defined(__x86_64__) && defined(__GNUC__)

namespace {

#define LFTRACK_AVX512 __attribute__((target("avx512f,avx512bw")))

// A storage mode's access to the samples. Pairs (the samples at t and t + 1 of one (u, v, s)
// row, for every lane) stay in the storage's own form (`Pairs`) until they have been selected
// by s row, then become floats (`split`); the interpolated value is finished once (`finish`:
// the 16-bit scale, which commutes with the interpolation).
//   corner(grid, iu, iv, is, it, k, ws, wt): the gather path, (u, v) cell k blended in (s, t)
//   kRuns:                  whether the storage has the run path:
//   run(offset, dt, dt1):   lane k's pair from the run of 32 samples at offset: dt_k, dt_k + 1
//   select(mask, x, y):     y in the mask's lanes, x elsewhere

// Sample-index strides of a field's u, v and s axes (t is contiguous), in every lane.
struct Grid {
  __m512i su, sv, ss;
};

template <class Samples>
LFTRACK_AVX512 inline __m512 blend_st(typename Samples::Pairs top, typename Samples::Pairs bottom, __m512 ws,
                                      __m512 wt);

// Gather path of the float and 16-bit storages: (u, v) cell k = 2 du + dv of every lane,
// blended in (s, t).
template <class Samples>
LFTRACK_AVX512 inline __m512 indexed_corner(const Samples& f, const Grid& grid, __m512i iu, __m512i iv,
                                            __m512i is, __m512i it, int k, __m512 ws, __m512 wt) {
  const __m512i u = _mm512_add_epi32(iu, _mm512_set1_epi32(k >> 1));
  const __m512i v = _mm512_add_epi32(iv, _mm512_set1_epi32(k & 1));
  const __m512i idx =
      _mm512_add_epi32(_mm512_add_epi32(_mm512_mullo_epi32(u, grid.su), _mm512_mullo_epi32(v, grid.sv)),
                       _mm512_add_epi32(_mm512_mullo_epi32(is, grid.ss), it));
  return blend_st<Samples>(f.gather(idx), f.gather(_mm512_add_epi32(idx, grid.ss)), ws, wt);
}

// Float samples.
struct FloatSamples {
  static constexpr bool kRuns = true;
  struct Pairs {
    __m512 first, second;
  };
  const float* f;
  LFTRACK_AVX512 inline Pairs gather(__m512i idx) const {
    const __mmask16 all = 0xffff;
    const __m512i next = _mm512_add_epi32(idx, _mm512_set1_epi32(1));
    return {_mm512_mask_i32gather_ps(_mm512_setzero_ps(), all, idx, f, 4),
            _mm512_mask_i32gather_ps(_mm512_setzero_ps(), all, next, f, 4)};
  }
  LFTRACK_AVX512 inline Pairs run(std::size_t offset, __m512i dt, __m512i dt_next) const {
    const __m512 lo = _mm512_loadu_ps(f + offset), hi = _mm512_loadu_ps(f + offset + 16);
    return {_mm512_permutex2var_ps(lo, dt, hi), _mm512_permutex2var_ps(lo, dt_next, hi)};
  }
  LFTRACK_AVX512 static inline Pairs select(__mmask16 mask, Pairs x, Pairs y) {
    return {_mm512_mask_blend_ps(mask, x.first, y.first), _mm512_mask_blend_ps(mask, x.second, y.second)};
  }
  LFTRACK_AVX512 static inline void split(Pairs p, __m512* first, __m512* second) {
    *first = p.first, *second = p.second;
  }
  LFTRACK_AVX512 inline __m512 finish(__m512 value) const { return value; }
  LFTRACK_AVX512 inline __m512 corner(const Grid& grid, __m512i iu, __m512i iv, __m512i is, __m512i it, int k,
                                      __m512 ws, __m512 wt) const {
    return indexed_corner(*this, grid, iu, iv, is, it, k, ws, wt);
  }
};

// 16-bit samples (value = code * scale): one 4-byte element holds a sample and its t neighbour.
struct Fixed16Samples {
  static constexpr bool kRuns = true;
  using Pairs = __m512i;  // low half: the sample at t, high half: at t + 1
  const std::uint16_t* q;
  float scale;
  LFTRACK_AVX512 inline Pairs gather(__m512i idx) const {
    // idx + 1 is always inside the field: t is clamped to size - 2.
    return _mm512_mask_i32gather_epi32(_mm512_setzero_si512(), 0xffff, idx, q, 2);
  }
  LFTRACK_AVX512 inline Pairs run(std::size_t offset, __m512i dt, __m512i dt_next) const {
    // Word indices: lane k's low half picks dt_k, its high half dt_k + 1.
    const __m512i words = _mm512_or_si512(dt, _mm512_slli_epi32(dt_next, 16));
    return _mm512_permutexvar_epi16(words, _mm512_loadu_si512(q + offset));
  }
  LFTRACK_AVX512 static inline Pairs select(__mmask16 mask, Pairs x, Pairs y) {
    return _mm512_mask_blend_epi32(mask, x, y);
  }
  LFTRACK_AVX512 static inline void split(Pairs p, __m512* first, __m512* second) {
    *first = _mm512_cvtepi32_ps(_mm512_and_si512(p, _mm512_set1_epi32(0xffff)));
    *second = _mm512_cvtepi32_ps(_mm512_srli_epi32(p, 16));
  }
  LFTRACK_AVX512 inline __m512 finish(__m512 value) const {
    return _mm512_mul_ps(value, _mm512_set1_ps(scale));
  }
  LFTRACK_AVX512 inline __m512 corner(const Grid& grid, __m512i iu, __m512i iv, __m512i is, __m512i it, int k,
                                      __m512 ws, __m512 wt) const {
    return indexed_corner(*this, grid, iu, iv, is, it, k, ws, wt);
  }
};

// Vector-quantised samples: one 16-bit codeword index per 2 x 2 x 2 x 2 tile, codewords of 16
// floats (element 8 du + 4 dv + 2 ds + dt). Gathers only: a sample costs a code and a codeword
// element.
struct VqSamples {
  static constexpr bool kRuns = false;
  using Pairs = FloatSamples::Pairs;
  const float* codebook;
  // The codes, read as the 4-byte words that end at each code: the codebook lies before the
  // codes (at least one 64-byte codeword), so no read leaves the field's payload.
  const std::uint16_t* codes;
  int tiles_v, tiles_s, tiles_t;
  LFTRACK_AVX512 static inline Pairs select(__mmask16 mask, Pairs x, Pairs y) {
    return FloatSamples::select(mask, x, y);
  }
  LFTRACK_AVX512 static inline void split(Pairs p, __m512* first, __m512* second) {
    FloatSamples::split(p, first, second);
  }
  LFTRACK_AVX512 inline __m512 finish(__m512 value) const { return value; }
  // Samples of one (u, v, s) row at t for every lane, given that row's tile offset and element
  // bits: tile + (t >> 1), element | (t & 1).
  LFTRACK_AVX512 inline __m512 at(__m512i row_tile, __m512i row_bits, __m512i t) const {
    const __mmask16 all = 0xffff;
    const __m512i tile = _mm512_add_epi32(row_tile, _mm512_srli_epi32(t, 1));
    const __m512i words = _mm512_mask_i32gather_epi32(_mm512_setzero_si512(), all,
                                                      _mm512_sub_epi32(tile, _mm512_set1_epi32(1)), codes, 2);
    const __m512i code = _mm512_srli_epi32(words, 16);
    const __m512i element = _mm512_or_si512(row_bits, _mm512_and_si512(t, _mm512_set1_epi32(1)));
    return _mm512_mask_i32gather_ps(_mm512_setzero_ps(), all,
                                    _mm512_add_epi32(_mm512_slli_epi32(code, 4), element), codebook, 4);
  }
  LFTRACK_AVX512 inline __m512 corner(const Grid&, __m512i iu, __m512i iv, __m512i is, __m512i it, int k,
                                      __m512 ws, __m512 wt) const {
    const __m512i one = _mm512_set1_epi32(1);
    const __m512i u = _mm512_add_epi32(iu, _mm512_set1_epi32(k >> 1));
    const __m512i v = _mm512_add_epi32(iv, _mm512_set1_epi32(k & 1));
    const __m512i uv_tile = _mm512_mullo_epi32(
        _mm512_add_epi32(_mm512_mullo_epi32(_mm512_srli_epi32(u, 1), _mm512_set1_epi32(tiles_v)),
                         _mm512_srli_epi32(v, 1)),
        _mm512_set1_epi32(tiles_s * tiles_t));
    const __m512i uv_bits = _mm512_or_si512(_mm512_slli_epi32(_mm512_and_si512(u, one), 3),
                                            _mm512_slli_epi32(_mm512_and_si512(v, one), 2));
    Pairs rows[2];
    for (int ds = 0; ds < 2; ++ds) {
      const __m512i s = _mm512_add_epi32(is, _mm512_set1_epi32(ds));
      const __m512i row_tile =
          _mm512_add_epi32(uv_tile, _mm512_mullo_epi32(_mm512_srli_epi32(s, 1), _mm512_set1_epi32(tiles_t)));
      const __m512i row_bits = _mm512_or_si512(uv_bits, _mm512_slli_epi32(_mm512_and_si512(s, one), 1));
      rows[ds] = {at(row_tile, row_bits, it), at(row_tile, row_bits, _mm512_add_epi32(it, one))};
    }
    return blend_st<VqSamples>(rows[0], rows[1], ws, wt);
  }
};

// Bilinear blend in (s, t) of a top and a bottom row pair.
template <class Samples>
LFTRACK_AVX512 inline __m512 blend_st(typename Samples::Pairs top, typename Samples::Pairs bottom, __m512 ws,
                                      __m512 wt) {
  __m512 a, b, c, d;
  Samples::split(top, &a, &b);
  Samples::split(bottom, &c, &d);
  const __m512 upper = _mm512_fmadd_ps(wt, _mm512_sub_ps(b, a), a);
  const __m512 lower = _mm512_fmadd_ps(wt, _mm512_sub_ps(d, c), c);
  return _mm512_fmadd_ps(ws, _mm512_sub_ps(lower, upper), upper);
}

LFTRACK_AVX512 inline int lane_value(__m512i v, int lane) {
  alignas(64) int values[16];
  _mm512_store_si512(values, v);
  return values[lane];
}

template <class Samples>
LFTRACK_AVX512 int render_avx512(const Samples& f, const LightFieldGeometry& g, const RayMap& m,
                                 ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin,
                                 int r_end) {
  const int nt = g.size[3];
  const std::size_t su = std::size_t(g.size[1]) * g.size[2] * g.size[3],
                    sv = std::size_t(g.size[2]) * g.size[3];
  const Grid grid{_mm512_set1_epi32(int(su)), _mm512_set1_epi32(int(sv)), _mm512_set1_epi32(nt)};
  const __m512i top_u = _mm512_set1_epi32(g.size[0] - 2), top_v = _mm512_set1_epi32(g.size[1] - 2);
  const __m512i top_s = _mm512_set1_epi32(g.size[2] - 2), top_t = _mm512_set1_epi32(g.size[3] - 2);
  const __m512i one = _mm512_set1_epi32(1);
  const __m512 zero = _mm512_setzero_ps();
  __m512 base[4], gain[4], limit[4];
  for (int a = 0; a < 4; ++a) {
    base[a] = _mm512_set1_ps(m.base[a]);
    gain[a] = _mm512_set1_ps(m.gain[a]);
    limit[a] = _mm512_set1_ps(m.limit[a]);
  }
  const __m512 lane = _mm512_setr_ps(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  int masked = 0;
  for (int r = r_begin; r < r_end; ++r) {
    const Eigen::Vector3d d_row = m.d00 + m.d_row * r;
    const __m512 dn0 = _mm512_set1_ps(float(d_row.dot(g.axis))),
                 dn1 = _mm512_set1_ps(float(m.d_col.dot(g.axis)));
    const __m512 de10 = _mm512_set1_ps(float(d_row.dot(g.e1))),
                 de11 = _mm512_set1_ps(float(m.d_col.dot(g.e1)));
    const __m512 de20 = _mm512_set1_ps(float(d_row.dot(g.e2))),
                 de21 = _mm512_set1_ps(float(m.d_col.dot(g.e2)));
    float* dst = out.row_ptr(r);
    unsigned char* ok_row = valid.data ? valid.row_ptr(r) : nullptr;
    for (int c = 0; c < cols; c += 16) {
      const int lanes = std::min(cols - c, 16);
      const __mmask16 in_row = static_cast<__mmask16>((1u << lanes) - 1u);
      const __m512 cf = _mm512_add_ps(_mm512_set1_ps(float(c)), lane);
      const __m512 dn = _mm512_fmadd_ps(dn1, cf, dn0);
      const __m512 inv = _mm512_div_ps(_mm512_set1_ps(1.0f), dn);
      const __m512 q1 = _mm512_mul_ps(_mm512_fmadd_ps(de11, cf, de10), inv);
      const __m512 q2 = _mm512_mul_ps(_mm512_fmadd_ps(de21, cf, de20), inv);
      const __m512 fu = _mm512_fmadd_ps(gain[0], q1, base[0]), fv = _mm512_fmadd_ps(gain[1], q2, base[1]);
      const __m512 fs = _mm512_fmadd_ps(gain[2], q1, base[2]), ft = _mm512_fmadd_ps(gain[3], q2, base[3]);
      // Ordered comparisons: NaN is outside. Lanes past the row's end are outside too.
      __mmask16 inside = _mm512_mask_cmp_ps_mask(in_row, dn, zero, _CMP_GT_OQ);
      inside = _mm512_mask_cmp_ps_mask(inside, fu, zero, _CMP_GE_OQ);
      inside = _mm512_mask_cmp_ps_mask(inside, fu, limit[0], _CMP_LE_OQ);
      inside = _mm512_mask_cmp_ps_mask(inside, fv, zero, _CMP_GE_OQ);
      inside = _mm512_mask_cmp_ps_mask(inside, fv, limit[1], _CMP_LE_OQ);
      inside = _mm512_mask_cmp_ps_mask(inside, fs, zero, _CMP_GE_OQ);
      inside = _mm512_mask_cmp_ps_mask(inside, fs, limit[2], _CMP_LE_OQ);
      inside = _mm512_mask_cmp_ps_mask(inside, ft, zero, _CMP_GE_OQ);
      inside = _mm512_mask_cmp_ps_mask(inside, ft, limit[3], _CMP_LE_OQ);
      const __m512 cu = _mm512_maskz_mov_ps(inside, fu), cv = _mm512_maskz_mov_ps(inside, fv);
      const __m512 cs = _mm512_maskz_mov_ps(inside, fs), ct = _mm512_maskz_mov_ps(inside, ft);
      const __m512i iu = _mm512_min_epi32(_mm512_cvttps_epi32(cu), top_u);
      const __m512i iv = _mm512_min_epi32(_mm512_cvttps_epi32(cv), top_v);
      const __m512i is = _mm512_min_epi32(_mm512_cvttps_epi32(cs), top_s);
      const __m512i it = _mm512_min_epi32(_mm512_cvttps_epi32(ct), top_t);
      const __m512 wu = _mm512_sub_ps(cu, _mm512_cvtepi32_ps(iu)),
                   wv = _mm512_sub_ps(cv, _mm512_cvtepi32_ps(iv));
      const __m512 ws = _mm512_sub_ps(cs, _mm512_cvtepi32_ps(is)),
                   wt = _mm512_sub_ps(ct, _mm512_cvtepi32_ps(it));

      __m512 corner[4];  // (u, v) cells (0,0), (0,1), (1,0), (1,1), each blended in (s, t)
      bool done = false;
      if constexpr (Samples::kRuns) {
        if (inside == 0xffff) {
          // The run test: one (u, v) cell for all lanes, t within 31 samples, s within three
          // rows. Lanes 0 and 15 give the range (t and s are monotonic along a row); every lane
          // is then checked against it, since rounding may bend monotonicity by a sample where
          // the coordinates barely change.
          const int u0 = lane_value(iu, 0), v0 = lane_value(iv, 0);
          const int t_first = lane_value(it, 0), t_last = lane_value(it, 15);
          const int s_first = lane_value(is, 0), s_last = lane_value(is, 15);
          const int t0 = std::min(t_first, t_last), s0 = std::min(s_first, s_last);
          const int t_span = std::max(t_first, t_last) - t0, s_span = std::max(s_first, s_last) - s0;
          const __mmask16 in_runs = _mm512_cmpeq_epi32_mask(iu, _mm512_set1_epi32(u0)) &
                                    _mm512_cmpeq_epi32_mask(iv, _mm512_set1_epi32(v0)) &
                                    _mm512_cmpge_epi32_mask(it, _mm512_set1_epi32(t0)) &
                                    _mm512_cmple_epi32_mask(it, _mm512_set1_epi32(t0 + t_span)) &
                                    _mm512_cmpge_epi32_mask(is, _mm512_set1_epi32(s0)) &
                                    _mm512_cmple_epi32_mask(is, _mm512_set1_epi32(s0 + s_span));
          if (in_runs == 0xffff && t_span <= 30 && s_span <= 2 && t0 + 32 <= nt) {
            const __m512i dt = _mm512_sub_epi32(it, _mm512_set1_epi32(t0));
            const __m512i dt_next = _mm512_add_epi32(dt, one);
            // Lanes whose top row is below s0 + 1 and s0 + 2.
            const __mmask16 below1 = _mm512_cmpgt_epi32_mask(is, _mm512_set1_epi32(s0));
            const __mmask16 below2 = _mm512_cmpgt_epi32_mask(is, _mm512_set1_epi32(s0 + 1));
            for (int k = 0; k < 4; ++k) {
              const std::size_t run0 = std::size_t(u0 + (k >> 1)) * su + std::size_t(v0 + (k & 1)) * sv +
                                       std::size_t(s0) * std::size_t(nt) + std::size_t(t0);
              // Rows s0 .. s0 + s_span + 1 (s0 + s_span <= size - 2); each lane's top row is
              // is - s0 of them, its bottom row the next.
              typename Samples::Pairs rows[4];
              for (int row = 0; row <= s_span + 1; ++row)
                rows[row] = f.run(run0 + std::size_t(row) * std::size_t(nt), dt, dt_next);
              typename Samples::Pairs top = rows[0], bottom = rows[1];
              if (s_span >= 1) {
                top = Samples::select(below1, top, rows[1]);
                bottom = Samples::select(below1, bottom, rows[2]);
              }
              if (s_span == 2) {
                top = Samples::select(below2, top, rows[2]);
                bottom = Samples::select(below2, bottom, rows[3]);
              }
              corner[k] = blend_st<Samples>(top, bottom, ws, wt);
            }
            done = true;
          }
        }
      }
      if (!done) {
        for (int k = 0; k < 4; ++k) corner[k] = f.corner(grid, iu, iv, is, it, k, ws, wt);
      }
      const __m512 low = _mm512_fmadd_ps(wv, _mm512_sub_ps(corner[1], corner[0]), corner[0]);
      const __m512 high = _mm512_fmadd_ps(wv, _mm512_sub_ps(corner[3], corner[2]), corner[2]);
      const __m512 value =
          _mm512_maskz_mov_ps(inside, f.finish(_mm512_fmadd_ps(wu, _mm512_sub_ps(high, low), low)));
      masked += lanes - __builtin_popcount(static_cast<unsigned>(inside));
      _mm512_mask_storeu_ps(dst + c, in_row, value);
      if (ok_row) {
        const __m128i flags = _mm512_cvtepi32_epi8(_mm512_maskz_mov_epi32(inside, one));
        if (lanes == 16) {
          _mm_storeu_si128(reinterpret_cast<__m128i*>(ok_row + c), flags);
        } else {
          alignas(16) unsigned char bytes[16];
          _mm_store_si128(reinterpret_cast<__m128i*>(bytes), flags);
          for (int k = 0; k < lanes; ++k) ok_row[c + k] = bytes[k];
        }
      }
    }
  }
  return masked;
}

}  // namespace

int render_float_avx512(const float* samples, const LightFieldGeometry& g, const RayMap& m,
                        ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin,
                        int r_end) {
  return render_avx512(FloatSamples{samples}, g, m, out, valid, cols, r_begin, r_end);
}

int render_fixed16_avx512(const std::uint16_t* codes, float scale, const LightFieldGeometry& g,
                          const RayMap& m, ImageView<float> out, ImageView<unsigned char> valid, int cols,
                          int r_begin, int r_end) {
  return render_avx512(Fixed16Samples{codes, scale}, g, m, out, valid, cols, r_begin, r_end);
}

int render_vq_avx512(const float* codebook, const std::uint16_t* codes, const LightFieldGeometry& g,
                     const RayMap& m, ImageView<float> out, ImageView<unsigned char> valid, int cols,
                     int r_begin, int r_end) {
  const VqSamples f{codebook, codes, (g.size[1] + 1) / 2, (g.size[2] + 1) / 2, (g.size[3] + 1) / 2};
  return render_avx512(f, g, m, out, valid, cols, r_begin, r_end);
}

#else

int render_float_avx512(const float*, const LightFieldGeometry&, const RayMap&, ImageView<float>,
                        ImageView<unsigned char>, int, int, int) {
  return 0;
}
int render_fixed16_avx512(const std::uint16_t*, float, const LightFieldGeometry&, const RayMap&,
                          ImageView<float>, ImageView<unsigned char>, int, int, int) {
  return 0;
}
int render_vq_avx512(const float*, const std::uint16_t*, const LightFieldGeometry&, const RayMap&,
                     ImageView<float>, ImageView<unsigned char>, int, int, int) {
  return 0;
}

#endif

}  // namespace lftrack::tracking
