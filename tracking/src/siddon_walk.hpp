#pragma once
// Private to the ray casters: where one Siddon walk starts, and the kernels that walk sixteen of
// them at once: AVX-512 (siddon_kernel_avx512.cpp) and AVX2 (siddon_kernel_avx2.cpp).

#include <cstddef>

namespace lftrack::tracking::detail {

// A Siddon walk through a volume, ready to step: the clipped parameter range [a, a_end] of the
// segment from + a (to - from), the first voxel's offset and, per axis, the parameter of the
// next plane crossing, the parameter step between crossings, the offset step and the planes
// still inside the volume. A ray that misses has a == a_end.
struct SiddonWalk {
  double a = 0, a_end = 0;
  double length = 0;  // |to - from|, mm: the walk's sum of mu * parameter times this is mu * mm
  double next[3] = {0, 0, 0}, delta[3] = {0, 0, 0};
  std::ptrdiff_t offset = 0, offset_step[3] = {0, 0, 0};
  int left[3] = {0, 0, 0};
};

// kLanes walks turned into one array per field, each aligned for a vector load: what the lane
// kernels load their registers from.
template <int kLanes>
struct WalkColumns {
  alignas(64) double a[kLanes], a_end[kLanes], next[3][kLanes], delta[3][kLanes];
  alignas(64) long long offset[kLanes], left[3][kLanes], offset_step[3][kLanes];
  explicit WalkColumns(const SiddonWalk* walks) {
    for (int k = 0; k < kLanes; ++k) {
      a[k] = walks[k].a;
      a_end[k] = walks[k].a_end;
      offset[k] = walks[k].offset;
      for (int axis = 0; axis < 3; ++axis) {
        next[axis][k] = walks[k].next[axis];
        delta[axis][k] = walks[k].delta[axis];
        left[axis][k] = walks[k].left[axis];
        offset_step[axis][k] = walks[k].offset_step[axis];
      }
    }
  }
};

// Sixteen walks at a time (two groups of eight AVX-512 lanes, or four groups of four AVX2 lanes,
// stepped in turn so that one group's dependency chain hides the others') need at least this
// many rays to be worth it.
inline constexpr int kSiddonLanes = 16;

// True if this CPU runs siddon_walk_avx512 (AVX-512F).
bool siddon_avx512_available();

// Walks kSiddonLanes walks through `mu` and writes each one's line integral (mu * mm) to
// `integrals`: bit for bit what GridRayCaster::siddon returns for the same ray. Needs
// siddon_avx512_available().
void siddon_walk_avx512(const float* mu, const SiddonWalk* walks, double* integrals);

// True if this CPU runs siddon_walk_avx2 (AVX2).
bool siddon_avx2_available();

// siddon_walk_avx512 for CPUs with AVX2: the same results, bit for bit. Needs
// siddon_avx2_available().
void siddon_walk_avx2(const float* mu, const SiddonWalk* walks, double* integrals);

}  // namespace lftrack::tracking::detail
