// The AVX2 light-field kernel for float storage: eight pixels of a row per iteration, the 16
// samples of each pixel fetched with gathers, t-neighbours in pairs. Compiled for AVX2 + FMA through function target
// attributes and chosen at run time, so the binary still runs on any x86-64 CPU.

#include "light_field_kernels.hpp"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

namespace lftrack::tracking {

#if defined(__x86_64__) && defined(__GNUC__)

bool light_field_avx2_available() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}

namespace {

#define LFTRACK_AVX2 __attribute__((target("avx2,fma")))

// The samples at idx and idx + 1 (adjacent in t) for 8 pixels, fetched as 4-byte pairs: two
// gathers of four 8-byte elements instead of two of eight 4-byte ones. The indices go in as
// pixels (0,1,4,5) and (2,3,6,7) so that the unpacking shuffles give pixel order back.
struct FloatPairs {
  const float* f;
  LFTRACK_AVX2 inline void operator()(__m256i idx, __m256* first, __m256* second) const;
};

// 16-bit samples: one gather of eight 4-byte words at idx reads both q[idx] and q[idx + 1]
// (idx + 1 is always inside the field: t is clamped to size - 2).
struct Fixed16Pairs {
  const std::uint16_t* q;
  float scale;
  LFTRACK_AVX2 inline void operator()(__m256i idx, __m256* first, __m256* second) const {
    const __m256i words = _mm256_mask_i32gather_epi32(_mm256_setzero_si256(), reinterpret_cast<const int*>(q), idx,
                                                      _mm256_set1_epi32(-1), 2);
    const __m256 s = _mm256_set1_ps(scale);
    *first = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_and_si256(words, _mm256_set1_epi32(0xffff))), s);
    *second = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_srli_epi32(words, 16)), s);
  }
};

LFTRACK_AVX2 inline void FloatPairs::operator()(__m256i idx, __m256* first, __m256* second) const {
  const __m256i order = _mm256_setr_epi32(0, 1, 4, 5, 2, 3, 6, 7);
  const __m256i p = _mm256_permutevar8x32_epi32(idx, order);
  const double* base = reinterpret_cast<const double*>(f);
  // The masked form with an explicit zero source (GCC 12 flags the plain form's undefined one).
  const __m256d zero = _mm256_setzero_pd();
  const __m256d all = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
  const __m256 x = _mm256_castpd_ps(_mm256_mask_i32gather_pd(zero, base, _mm256_castsi256_si128(p), all, 4));
  const __m256 y = _mm256_castpd_ps(_mm256_mask_i32gather_pd(zero, base, _mm256_extracti128_si256(p, 1), all, 4));
  *first = _mm256_shuffle_ps(x, y, _MM_SHUFFLE(2, 0, 2, 0));
  *second = _mm256_shuffle_ps(x, y, _MM_SHUFFLE(3, 1, 3, 1));
}

// Bilinear blend in (s, t) of the 2 x 2 samples at idx, idx + 1, idx + ns_t, idx + ns_t + 1.
template <class Pairs>
LFTRACK_AVX2 inline __m256 bilinear(const Pairs& pairs, __m256i idx, __m256i stride_s, __m256 ws, __m256 wt) {
  __m256 a, b, c, d;
  pairs(idx, &a, &b);
  pairs(_mm256_add_epi32(idx, stride_s), &c, &d);
  const __m256 top = _mm256_fmadd_ps(wt, _mm256_sub_ps(b, a), a);
  const __m256 bottom = _mm256_fmadd_ps(wt, _mm256_sub_ps(d, c), c);
  return _mm256_fmadd_ps(ws, _mm256_sub_ps(bottom, top), top);
}

template <class Pairs>
LFTRACK_AVX2 int render_avx2(const Pairs& f, const LightFieldGeometry& g, const RayMap& m, ImageView<float> out,
                             ImageView<unsigned char> valid, int cols, int r_begin, int r_end) {
  const int su = g.size[1] * g.size[2] * g.size[3], sv = g.size[2] * g.size[3], ss = g.size[3];
  const __m256i v_su = _mm256_set1_epi32(su), v_sv = _mm256_set1_epi32(sv), v_ss = _mm256_set1_epi32(ss);
  const __m256i top_u = _mm256_set1_epi32(g.size[0] - 2), top_v = _mm256_set1_epi32(g.size[1] - 2);
  const __m256i top_s = _mm256_set1_epi32(g.size[2] - 2), top_t = _mm256_set1_epi32(g.size[3] - 2);
  const __m256 zero = _mm256_setzero_ps();
  __m256 base[4], gain[4], limit[4];
  for (int a = 0; a < 4; ++a) {
    base[a] = _mm256_set1_ps(m.base[a]);
    gain[a] = _mm256_set1_ps(m.gain[a]);
    limit[a] = _mm256_set1_ps(m.limit[a]);
  }
  const __m256 lane = _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7);
  int masked = 0;
  for (int r = r_begin; r < r_end; ++r) {
    const Eigen::Vector3d d_row = m.d00 + m.d_row * r;
    const __m256 dn0 = _mm256_set1_ps(float(d_row.dot(g.axis))), dn1 = _mm256_set1_ps(float(m.d_col.dot(g.axis)));
    const __m256 de10 = _mm256_set1_ps(float(d_row.dot(g.e1))), de11 = _mm256_set1_ps(float(m.d_col.dot(g.e1)));
    const __m256 de20 = _mm256_set1_ps(float(d_row.dot(g.e2))), de21 = _mm256_set1_ps(float(m.d_col.dot(g.e2)));
    float* dst = out.row_ptr(r);
    unsigned char* ok_row = valid.data ? valid.row_ptr(r) : nullptr;
    for (int c = 0; c < cols; c += 8) {
      const __m256 cf = _mm256_add_ps(_mm256_set1_ps(float(c)), lane);
      const __m256 dn = _mm256_fmadd_ps(dn1, cf, dn0);
      const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), dn);
      const __m256 q1 = _mm256_mul_ps(_mm256_fmadd_ps(de11, cf, de10), inv);
      const __m256 q2 = _mm256_mul_ps(_mm256_fmadd_ps(de21, cf, de20), inv);
      const __m256 fu = _mm256_fmadd_ps(gain[0], q1, base[0]), fv = _mm256_fmadd_ps(gain[1], q2, base[1]);
      const __m256 fs = _mm256_fmadd_ps(gain[2], q1, base[2]), ft = _mm256_fmadd_ps(gain[3], q2, base[3]);
      // Ordered comparisons: NaN is outside.
      __m256 inside = _mm256_cmp_ps(dn, zero, _CMP_GT_OQ);
      inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(fu, zero, _CMP_GE_OQ), _mm256_cmp_ps(fu, limit[0], _CMP_LE_OQ)));
      inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(fv, zero, _CMP_GE_OQ), _mm256_cmp_ps(fv, limit[1], _CMP_LE_OQ)));
      inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(fs, zero, _CMP_GE_OQ), _mm256_cmp_ps(fs, limit[2], _CMP_LE_OQ)));
      inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(ft, zero, _CMP_GE_OQ), _mm256_cmp_ps(ft, limit[3], _CMP_LE_OQ)));
      // Lanes past the row's end are outside too.
      const int lanes = cols - c < 8 ? cols - c : 8;
      inside = _mm256_and_ps(inside, _mm256_cmp_ps(lane, _mm256_set1_ps(float(lanes)), _CMP_LT_OQ));
      const __m256 cu = _mm256_and_ps(fu, inside), cv = _mm256_and_ps(fv, inside);
      const __m256 cs = _mm256_and_ps(fs, inside), ct = _mm256_and_ps(ft, inside);
      const __m256i iu = _mm256_min_epi32(_mm256_cvttps_epi32(cu), top_u);
      const __m256i iv = _mm256_min_epi32(_mm256_cvttps_epi32(cv), top_v);
      const __m256i is = _mm256_min_epi32(_mm256_cvttps_epi32(cs), top_s);
      const __m256i it = _mm256_min_epi32(_mm256_cvttps_epi32(ct), top_t);
      const __m256 wu = _mm256_sub_ps(cu, _mm256_cvtepi32_ps(iu)), wv = _mm256_sub_ps(cv, _mm256_cvtepi32_ps(iv));
      const __m256 ws = _mm256_sub_ps(cs, _mm256_cvtepi32_ps(is)), wt = _mm256_sub_ps(ct, _mm256_cvtepi32_ps(it));
      const __m256i st = _mm256_add_epi32(_mm256_mullo_epi32(is, v_ss), it);
      const __m256i i00 = _mm256_add_epi32(_mm256_add_epi32(_mm256_mullo_epi32(iu, v_su), _mm256_mullo_epi32(iv, v_sv)), st);
      const __m256i i01 = _mm256_add_epi32(i00, v_sv);
      const __m256i i10 = _mm256_add_epi32(i00, v_su);
      const __m256i i11 = _mm256_add_epi32(i10, v_sv);
      const __m256 s00 = bilinear(f, i00, v_ss, ws, wt), s01 = bilinear(f, i01, v_ss, ws, wt);
      const __m256 s10 = bilinear(f, i10, v_ss, ws, wt), s11 = bilinear(f, i11, v_ss, ws, wt);
      const __m256 low = _mm256_fmadd_ps(wv, _mm256_sub_ps(s01, s00), s00);
      const __m256 high = _mm256_fmadd_ps(wv, _mm256_sub_ps(s11, s10), s10);
      const __m256 value = _mm256_and_ps(_mm256_fmadd_ps(wu, _mm256_sub_ps(high, low), low), inside);
      const int inside_bits = _mm256_movemask_ps(inside);
      masked += lanes - __builtin_popcount(static_cast<unsigned>(inside_bits));
      if (lanes == 8) {
        _mm256_storeu_ps(dst + c, value);
      } else {
        alignas(32) float tail[8];
        _mm256_store_ps(tail, value);
        for (int k = 0; k < lanes; ++k) dst[c + k] = tail[k];
      }
      if (ok_row) {
        for (int k = 0; k < lanes; ++k) ok_row[c + k] = static_cast<unsigned char>((inside_bits >> k) & 1);
      }
    }
  }
  return masked;
}

}  // namespace

int render_float_avx2(const float* samples, const LightFieldGeometry& g, const RayMap& m, ImageView<float> out,
                      ImageView<unsigned char> valid, int cols, int r_begin, int r_end) {
  return render_avx2(FloatPairs{samples}, g, m, out, valid, cols, r_begin, r_end);
}

int render_fixed16_avx2(const std::uint16_t* codes, float scale, const LightFieldGeometry& g, const RayMap& m,
                        ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin, int r_end) {
  return render_avx2(Fixed16Pairs{codes, scale}, g, m, out, valid, cols, r_begin, r_end);
}

#else

bool light_field_avx2_available() { return false; }
int render_float_avx2(const float*, const LightFieldGeometry&, const RayMap&, ImageView<float>, ImageView<unsigned char>,
                      int, int, int) {
  return 0;
}
int render_fixed16_avx2(const std::uint16_t*, float, const LightFieldGeometry&, const RayMap&, ImageView<float>,
                        ImageView<unsigned char>, int, int, int) {
  return 0;
}

#endif

}  // namespace lftrack::tracking
