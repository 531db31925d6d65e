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
// are loaded and scaled once at the end (the scale commutes with the interpolation). The lanes,
// runs and blends are in light_field_avx2_lanes.hpp; the source image's AVX2 render
// (light_field_source_image_avx2.cpp) shares its lanes, row rays and blend.
//
// The results equal the scalar kernel's up to float rounding (fused multiply-adds). Compiled for
// AVX2 + FMA through function target attributes and chosen at run time, so the binary still runs
// on any x86-64 CPU.

#include <cstddef>
#include <cstdint>

#include "light_field_avx2_lanes.hpp"
#include "light_field_kernels.hpp"

namespace lftrack::tracking {

#if defined(__x86_64__) && defined(__GNUC__)

bool light_field_avx2_available() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}

namespace {

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

bool light_field_avx2_available() { return false; }
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
