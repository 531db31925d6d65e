// The Siddon walk on AVX-512: eight rays a vector, two vectors in flight.
//
// The scalar walk (ray_integrals.cpp) is bound by its loop-carried chain (compare, select, add:
// about seven cycles a voxel crossing, whatever the CPU's width). Here each lane is one ray:
// a step takes the lane's nearest crossing on any axis, adds mu times the segment ending there,
// and moves to the next voxel; lanes whose ray has ended add zero-length segments and stay put.
// Two independent groups of eight are stepped in turn so that the out-of-order core overlaps
// their chains. Ties between axes are taken in the order x, y, z (the scalar walk takes its
// most-crossed axis first); either way the extra step has zero length and adds exactly 0.
//
// Results equal the scalar walk bit for bit: the same start, the same crossings summed in the
// same order with the same roundings. The file is compiled with -ffp-contract=off so that the
// compiler does not fuse the multiply and the add (the scalar build has no FMA).
// Compiled for AVX-512F through a function target attribute and chosen at run time, so the
// binary still runs on any x86-64 CPU.

#include "siddon_walk.hpp"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

namespace lftrack::tracking::detail {

#if defined(__x86_64__) && defined(__GNUC__)

namespace {

#define LFTRACK_AVX512 __attribute__((target("avx512f")))

// Eight walks in vector registers. `live` says whether any lane still has crossings ahead.
struct Lanes {
  __m512d a, a_end, next_x, next_y, next_z, delta_x, delta_y, delta_z, sum;
  __m512i offset, left_x, left_y, left_z, step_x, step_y, step_z;
  bool live;
};

LFTRACK_AVX512 Lanes load(const SiddonWalk* w) {
  const WalkColumns<8> c(w);
  Lanes l;
  l.a = _mm512_load_pd(c.a), l.a_end = _mm512_load_pd(c.a_end);
  l.next_x = _mm512_load_pd(c.next[0]), l.next_y = _mm512_load_pd(c.next[1]), l.next_z = _mm512_load_pd(c.next[2]);
  l.delta_x = _mm512_load_pd(c.delta[0]), l.delta_y = _mm512_load_pd(c.delta[1]);
  l.delta_z = _mm512_load_pd(c.delta[2]);
  l.sum = _mm512_setzero_pd();
  l.offset = _mm512_load_si512(c.offset);
  l.left_x = _mm512_load_si512(c.left[0]), l.left_y = _mm512_load_si512(c.left[1]);
  l.left_z = _mm512_load_si512(c.left[2]);
  l.step_x = _mm512_load_si512(c.offset_step[0]), l.step_y = _mm512_load_si512(c.offset_step[1]);
  l.step_z = _mm512_load_si512(c.offset_step[2]);
  l.live = true;
  return l;
}

// One crossing for every lane.
LFTRACK_AVX512 inline void step(const float* mu, Lanes& l) {
  const __m512i one = _mm512_set1_epi64(1), zero = _mm512_setzero_si512();
  const __m512d nearest = _mm512_min_pd(l.next_x, _mm512_min_pd(l.next_y, l.next_z));
  const __mmask8 go = _mm512_cmp_pd_mask(nearest, l.a_end, _CMP_LT_OQ);
  // The segment in the current voxel ends at the crossing, or at the ray's end.
  const __m512d end = _mm512_mask_blend_pd(go, l.a_end, nearest);
  const __m512d mu_here = _mm512_cvtps_pd(_mm512_i64gather_ps(l.offset, mu, 4));
  l.sum = _mm512_add_pd(l.sum, _mm512_mul_pd(mu_here, _mm512_sub_pd(end, l.a)));
  l.a = end;
  l.live = go != 0;
  const __mmask8 sx = _mm512_mask_cmp_pd_mask(go, l.next_x, nearest, _CMP_EQ_OQ);
  const __mmask8 sy = _mm512_mask_cmp_pd_mask(go & ~sx, l.next_y, nearest, _CMP_EQ_OQ);
  const __mmask8 sz = go & ~(sx | sy);
  l.left_x = _mm512_mask_sub_epi64(l.left_x, sx, l.left_x, one);
  l.left_y = _mm512_mask_sub_epi64(l.left_y, sy, l.left_y, one);
  l.left_z = _mm512_mask_sub_epi64(l.left_z, sz, l.left_z, one);
  // A crossing that rounding placed before a_end but beyond the last plane ends the lane there
  // (the scalar walk returns at that point) and keeps its offset inside the volume.
  const __mmask8 out =
      _mm512_cmplt_epi64_mask(_mm512_or_si512(l.left_x, _mm512_or_si512(l.left_y, l.left_z)), zero);
  l.a_end = _mm512_mask_mov_pd(l.a_end, out, l.a);
  const __m512i offset_step =
      _mm512_mask_mov_epi64(_mm512_mask_mov_epi64(l.step_z, sy, l.step_y), sx, l.step_x);
  l.offset = _mm512_mask_add_epi64(l.offset, go & ~out, l.offset, offset_step);
  l.next_x = _mm512_mask_add_pd(l.next_x, sx, l.next_x, l.delta_x);
  l.next_y = _mm512_mask_add_pd(l.next_y, sy, l.next_y, l.delta_y);
  l.next_z = _mm512_mask_add_pd(l.next_z, sz, l.next_z, l.delta_z);
}

}  // namespace

LFTRACK_AVX512 void siddon_walk_avx512(const float* mu, const SiddonWalk* walks, double* integrals) {
  static_assert(kSiddonLanes == 16);
  Lanes first = load(walks), second = load(walks + 8);
  while (first.live && second.live) {
    step(mu, first);
    step(mu, second);
  }
  while (first.live) step(mu, first);
  while (second.live) step(mu, second);
  alignas(64) double sums[16];
  _mm512_store_pd(sums, first.sum);
  _mm512_store_pd(sums + 8, second.sum);
  for (int k = 0; k < 16; ++k) integrals[k] = sums[k] * walks[k].length;
}

#else

void siddon_walk_avx512(const float*, const SiddonWalk*, double*) {}

#endif

}  // namespace lftrack::tracking::detail
