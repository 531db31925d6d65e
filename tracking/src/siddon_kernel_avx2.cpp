// The Siddon walk on AVX2: four rays a vector, four vectors in flight.
//
// The same walk as siddon_kernel_avx512.cpp (read its header first) for CPUs with AVX2 and no
// AVX-512, such as AMD's Zen 2 and Zen 3: each lane is one ray; a step takes the lane's nearest
// crossing on any axis, adds mu times the segment ending there and moves to the next voxel;
// lanes whose ray has ended add zero-length segments and stay put. Four independent groups of
// four lanes are stepped in turn so that the out-of-order core overlaps their chains (a step's
// chain, compare -> blend -> add, is about as long as the scalar walk's; four groups hide it).
// AVX2 has no mask registers, so a lane's choice is an all-ones or all-zeros double and every
// masked update is a blend: the values left unchosen are bit for bit untouched.
//
// Results equal the scalar walk bit for bit (tested ray by ray in ray_integrals_test.cpp). The
// file is compiled with -ffp-contract=off, like the AVX-512 kernel, so that no multiply and add
// are fused. Compiled for AVX2 through a function target attribute and chosen at run time.

#include "siddon_walk.hpp"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

namespace lftrack::tracking::detail {

#if defined(__x86_64__) && defined(__GNUC__)

namespace {

#define LFTRACK_AVX2 __attribute__((target("avx2")))

// Four walks in vector registers. `live` says whether any lane still has crossings ahead.
struct Lanes {
  __m256d a, a_end, next_x, next_y, next_z, delta_x, delta_y, delta_z, sum;
  __m256i offset, left_x, left_y, left_z, step_x, step_y, step_z;
  bool live;
};

LFTRACK_AVX2 inline __m256i load_ints(const long long* v) {
  return _mm256_load_si256(reinterpret_cast<const __m256i*>(v));
}

LFTRACK_AVX2 Lanes load(const SiddonWalk* w) {
  const WalkColumns<4> c(w);
  Lanes l;
  l.a = _mm256_load_pd(c.a), l.a_end = _mm256_load_pd(c.a_end);
  l.next_x = _mm256_load_pd(c.next[0]), l.next_y = _mm256_load_pd(c.next[1]), l.next_z = _mm256_load_pd(c.next[2]);
  l.delta_x = _mm256_load_pd(c.delta[0]), l.delta_y = _mm256_load_pd(c.delta[1]);
  l.delta_z = _mm256_load_pd(c.delta[2]);
  l.sum = _mm256_setzero_pd();
  l.offset = load_ints(c.offset);
  l.left_x = load_ints(c.left[0]), l.left_y = load_ints(c.left[1]), l.left_z = load_ints(c.left[2]);
  l.step_x = load_ints(c.offset_step[0]), l.step_y = load_ints(c.offset_step[1]);
  l.step_z = load_ints(c.offset_step[2]);
  l.live = true;
  return l;
}

// One crossing for every lane.
LFTRACK_AVX2 inline void step(const float* mu, Lanes& l) {
  const __m256d nearest = _mm256_min_pd(l.next_x, _mm256_min_pd(l.next_y, l.next_z));
  const __m256d go = _mm256_cmp_pd(nearest, l.a_end, _CMP_LT_OQ);
  // The segment in the current voxel ends at the crossing, or at the ray's end.
  const __m256d end = _mm256_blendv_pd(l.a_end, nearest, go);
  // Four scalar loads, not _mm256_i64gather_ps: on Zen 3 the gather made the whole walk about
  // 1.3x slower (BM_SiddonBatch).
  alignas(32) long long o[4];
  _mm256_store_si256(reinterpret_cast<__m256i*>(o), l.offset);
  const __m256d mu_here = _mm256_cvtps_pd(_mm_setr_ps(mu[o[0]], mu[o[1]], mu[o[2]], mu[o[3]]));
  l.sum = _mm256_add_pd(l.sum, _mm256_mul_pd(mu_here, _mm256_sub_pd(end, l.a)));
  l.a = end;
  l.live = _mm256_movemask_pd(go) != 0;
  // The axis crossed: x, else y, else z (ties: see siddon_kernel_avx512.cpp).
  const __m256d sx = _mm256_and_pd(go, _mm256_cmp_pd(l.next_x, nearest, _CMP_EQ_OQ));
  const __m256d sy = _mm256_andnot_pd(sx, _mm256_and_pd(go, _mm256_cmp_pd(l.next_y, nearest, _CMP_EQ_OQ)));
  const __m256d sz = _mm256_andnot_pd(_mm256_or_pd(sx, sy), go);
  const __m256i sxi = _mm256_castpd_si256(sx), syi = _mm256_castpd_si256(sy), szi = _mm256_castpd_si256(sz);
  // A chosen lane's mask is -1: adding it counts one plane off.
  l.left_x = _mm256_add_epi64(l.left_x, sxi);
  l.left_y = _mm256_add_epi64(l.left_y, syi);
  l.left_z = _mm256_add_epi64(l.left_z, szi);
  // A crossing that rounding placed before a_end but beyond the last plane ends the lane there
  // (the scalar walk returns at that point) and keeps its offset inside the volume.
  const __m256i out = _mm256_cmpgt_epi64(_mm256_setzero_si256(),
                                         _mm256_or_si256(l.left_x, _mm256_or_si256(l.left_y, l.left_z)));
  l.a_end = _mm256_blendv_pd(l.a_end, l.a, _mm256_castsi256_pd(out));
  const __m256i offset_step = _mm256_blendv_epi8(_mm256_blendv_epi8(l.step_z, l.step_y, syi), l.step_x, sxi);
  const __m256i moves = _mm256_andnot_si256(out, _mm256_castpd_si256(go));
  l.offset = _mm256_add_epi64(l.offset, _mm256_and_si256(offset_step, moves));
  l.next_x = _mm256_blendv_pd(l.next_x, _mm256_add_pd(l.next_x, l.delta_x), sx);
  l.next_y = _mm256_blendv_pd(l.next_y, _mm256_add_pd(l.next_y, l.delta_y), sy);
  l.next_z = _mm256_blendv_pd(l.next_z, _mm256_add_pd(l.next_z, l.delta_z), sz);
}

}  // namespace

LFTRACK_AVX2 void siddon_walk_avx2(const float* mu, const SiddonWalk* walks, double* integrals) {
  static_assert(kSiddonLanes == 16);
  Lanes g[4] = {load(walks), load(walks + 4), load(walks + 8), load(walks + 12)};
  while (g[0].live && g[1].live && g[2].live && g[3].live) {
    step(mu, g[0]);
    step(mu, g[1]);
    step(mu, g[2]);
    step(mu, g[3]);
  }
  for (Lanes& l : g) {
    while (l.live) step(mu, l);
  }
  alignas(32) double sums[16];
  for (int k = 0; k < 4; ++k) _mm256_store_pd(sums + 4 * k, g[k].sum);
  for (int k = 0; k < 16; ++k) integrals[k] = sums[k] * walks[k].length;
}

#else

void siddon_walk_avx2(const float*, const SiddonWalk*, double*) {}

#endif

}  // namespace lftrack::tracking::detail
