// The AVX2 light-field kernels for float and 16-bit storage: eight pixels of a row per iteration
// and, wherever possible, no gathers.
//
// As in the AVX-512 kernel (light_field_kernel_avx512.cpp, which explains why), eight
// neighbouring pixels of a row usually share their four (u, v) cells, their t indices rise or
// fall over a few samples and their s indices span at most three rows. Then each (u, v) cell's
// samples for all eight pixels lie in runs of consecutive samples, one per s row: the kernel
// loads a run and hands each pixel its pair (t, t + 1) with vpermps. Where the eight t indices
// span at most 6 samples (the full-resolution windows and the 256 x 256 benchmark image) a run
// is one register and each sample of the pair one permutation; where they span up to 14 (2 x 2
// binned windows) a run is two registers, each sample two permutations and a blend. Chunks that
// do not qualify (the field's edges, out-of-field pixels, a row's tail, a (u, v) cell boundary)
// take the gather path with the same arithmetic. 16-bit samples are converted to float as they
// are loaded and scaled once at the end (the scale commutes with the interpolation). The (s, t)
// blend, the rays in lanes and the chunk's store are in light_field_avx2_lanes.hpp, shared with
// the source image's AVX2 render (light_field_source_image_avx2.cpp).
//
// The results equal the scalar kernel's up to float rounding (fused multiply-adds). Compiled for
// AVX2 + FMA through function target attributes and chosen at run time, so the binary still runs
// on any x86-64 CPU.

#include <algorithm>
#include <cstddef>
#include <cstdint>

#include "light_field_avx2_lanes.hpp"
#include "light_field_kernels.hpp"

namespace lftrack::tracking {

#if defined(__x86_64__) && defined(__GNUC__)

namespace {

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

template <class Samples>
LFTRACK_AVX2 int render_avx2(const Samples& f, const LightFieldGeometry& g, const RayMap& m, ImageView<float> out,
                             ImageView<unsigned char> valid, int cols, int r_begin, int r_end, bool runs) {
  const int nt = g.size[3];
  const std::size_t su = std::size_t(g.size[1]) * g.size[2] * g.size[3], sv = std::size_t(g.size[2]) * g.size[3];
  const __m256i v_su = _mm256_set1_epi32(int(su)), v_sv = _mm256_set1_epi32(int(sv)), v_ss = _mm256_set1_epi32(nt);
  const __m256i top_u = _mm256_set1_epi32(g.size[0] - 2), top_v = _mm256_set1_epi32(g.size[1] - 2);
  const __m256i top_s = _mm256_set1_epi32(g.size[2] - 2), top_t = _mm256_set1_epi32(g.size[3] - 2);
  const __m256 zero = _mm256_setzero_ps();
  const MapLanes map(m);
  const bool all_inside = rows_inside_field(g, m, r_begin, r_end - 1, cols);  // else one test a row
  int masked = 0;
  for (int r = r_begin; r < r_end; ++r) {
    const RowRays row = row_rays(g, m, r, all_inside || row_inside_field(g, m, r, cols));
    float* dst = out.row_ptr(r);
    unsigned char* ok_row = valid.data ? valid.row_ptr(r) : nullptr;
    for (int c = 0; c < cols; c += 8) {
      const ChunkRays k = chunk_rays(row, map, c, cols);
      const __m256i iu = _mm256_min_epi32(_mm256_cvttps_epi32(k.cu), top_u);
      const __m256i iv = _mm256_min_epi32(_mm256_cvttps_epi32(k.cv), top_v);
      const __m256i is = _mm256_min_epi32(_mm256_cvttps_epi32(k.cs), top_s);
      const __m256i it = _mm256_min_epi32(_mm256_cvttps_epi32(k.ct), top_t);
      const __m256 wu = _mm256_sub_ps(k.cu, _mm256_cvtepi32_ps(iu)), wv = _mm256_sub_ps(k.cv, _mm256_cvtepi32_ps(iv));
      const __m256 ws = _mm256_sub_ps(k.cs, _mm256_cvtepi32_ps(is)), wt = _mm256_sub_ps(k.ct, _mm256_cvtepi32_ps(it));

      // (u, v) cells (0,0), (0,1), (1,0), (1,1), each blended in (s, t).
      __m256 corner0 = zero, corner1 = zero, corner2 = zero, corner3 = zero;
      bool done = false;
      if (runs && k.inside_bits == 0xff) {
        // The run test, and one (u, v) cell for every lane.
        const int u0 = first_lane(iu), v0 = first_lane(iv);
        const RunRange range = run_range(
            is, it, _mm256_or_si256(_mm256_xor_si256(iu, _mm256_set1_epi32(u0)), _mm256_xor_si256(iv, _mm256_set1_epi32(v0))));
        if (range.ok) {
          const RunLanes l = run_lanes(is, it, range);
          const std::size_t run0 = std::size_t(u0) * su + std::size_t(v0) * sv +
                                   std::size_t(range.s0) * std::size_t(nt) + std::size_t(range.t0);
          const std::size_t n_t = std::size_t(nt);
          // A run must not read past its (u, v, s) row's samples.
          if (range.t_span <= 6 && range.t0 + 8 <= nt) {
            corner0 = run_cell<Samples, false>(f, run0, n_t, range.s_span, l, ws, wt);
            corner1 = run_cell<Samples, false>(f, run0 + sv, n_t, range.s_span, l, ws, wt);
            corner2 = run_cell<Samples, false>(f, run0 + su, n_t, range.s_span, l, ws, wt);
            corner3 = run_cell<Samples, false>(f, run0 + su + sv, n_t, range.s_span, l, ws, wt);
            done = true;
          } else if (range.t0 + 16 <= nt) {
            corner0 = run_cell<Samples, true>(f, run0, n_t, range.s_span, l, ws, wt);
            corner1 = run_cell<Samples, true>(f, run0 + sv, n_t, range.s_span, l, ws, wt);
            corner2 = run_cell<Samples, true>(f, run0 + su, n_t, range.s_span, l, ws, wt);
            corner3 = run_cell<Samples, true>(f, run0 + su + sv, n_t, range.s_span, l, ws, wt);
            done = true;
          }
        }
      }
      if (!done) {
        const __m256i st = _mm256_add_epi32(_mm256_mullo_epi32(is, v_ss), it);
        const __m256i i00 =
            _mm256_add_epi32(_mm256_add_epi32(_mm256_mullo_epi32(iu, v_su), _mm256_mullo_epi32(iv, v_sv)), st);
        const __m256i i10 = _mm256_add_epi32(i00, v_su);
        corner0 = gathered_cell(f, i00, v_ss, ws, wt);
        corner1 = gathered_cell(f, _mm256_add_epi32(i00, v_sv), v_ss, ws, wt);
        corner2 = gathered_cell(f, i10, v_ss, ws, wt);
        corner3 = gathered_cell(f, _mm256_add_epi32(i10, v_sv), v_ss, ws, wt);
      }
      const __m256 low = _mm256_fmadd_ps(wv, _mm256_sub_ps(corner1, corner0), corner0);
      const __m256 high = _mm256_fmadd_ps(wv, _mm256_sub_ps(corner3, corner2), corner2);
      masked += k.lanes - __builtin_popcount(static_cast<unsigned>(k.inside_bits));
      store_chunk(k, f.finish(_mm256_fmadd_ps(wu, _mm256_sub_ps(high, low), low)), dst + c, ok_row ? ok_row + c : nullptr);
    }
  }
  return masked;
}

}  // namespace

int render_float_avx2(const float* samples, const LightFieldGeometry& g, const RayMap& m, ImageView<float> out,
                      ImageView<unsigned char> valid, int cols, int r_begin, int r_end, bool runs) {
  return render_avx2(FloatSamples{samples}, g, m, out, valid, cols, r_begin, r_end, runs);
}

int render_fixed16_avx2(const std::uint16_t* codes, float scale, const LightFieldGeometry& g, const RayMap& m,
                        ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin, int r_end,
                        bool runs) {
  return render_avx2(Fixed16Samples{codes, scale}, g, m, out, valid, cols, r_begin, r_end, runs);
}

#else

int render_float_avx2(const float*, const LightFieldGeometry&, const RayMap&, ImageView<float>, ImageView<unsigned char>,
                      int, int, int, bool) {
  return 0;
}
int render_fixed16_avx2(const std::uint16_t*, float, const LightFieldGeometry&, const RayMap&, ImageView<float>,
                        ImageView<unsigned char>, int, int, int, bool) {
  return 0;
}

#endif

}  // namespace lftrack::tracking
