#include "lftrack/tracking/ray_integrals.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "cpu_dispatch.hpp"
#include "siddon_walk.hpp"

namespace lftrack::tracking {

GridRayCaster::GridRayCaster(const MuVolume& volume) : volume_(volume) {
  lower_mm_ = -0.5 * volume.geometry.spacing_mm;
  upper_mm_ = (volume.geometry.size.cast<double>() - Eigen::Vector3d::Constant(0.5))
                  .cwiseProduct(volume.geometry.spacing_mm);
}

bool GridRayCaster::clip(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1, double* a_enter,
                         double* a_exit) const {
  if (!p0.allFinite() || !p1.allFinite()) return false;
  const Eigen::Vector3d d = p1 - p0;
  double amin = 0.0, amax = 1.0;
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0.0) {
      if (p0[a] < lower_mm_[a] || p0[a] >= upper_mm_[a]) return false;
      continue;
    }
    const double t0 = (lower_mm_[a] - p0[a]) / d[a];
    const double t1 = (upper_mm_[a] - p0[a]) / d[a];
    amin = std::max(amin, std::min(t0, t1));
    amax = std::min(amax, std::max(t0, t1));
  }
  if (!(amax > amin)) return false;  // also false for NaN input
  *a_enter = amin;
  *a_exit = amax;
  return true;
}

bool GridRayCaster::start_walk(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1,
                               detail::SiddonWalk* w) const {
  if (!clip(p0, p1, &w->a, &w->a_end)) return false;
  const Eigen::Vector3d d = p1 - p0;
  const VolumeGeometry& g = volume_.geometry;
  const Eigen::Vector3d entry = p0 + w->a * d;
  const std::ptrdiff_t stride[3] = {1, g.size.x(), std::ptrdiff_t{g.size.x()} * g.size.y()};
  int index[3];
  for (int ax = 0; ax < 3; ++ax) {
    const double s = g.spacing_mm[ax];
    const int n = g.size[ax];
    const double u = (entry[ax] - lower_mm_[ax]) / s;  // position in voxel units from the box
    if (d[ax] > 0) {
      index[ax] = std::clamp(static_cast<int>(std::floor(u)), 0, n - 1);
      w->next[ax] = (lower_mm_[ax] + (index[ax] + 1) * s - p0[ax]) / d[ax];
      w->delta[ax] = s / d[ax];
      w->offset_step[ax] = stride[ax];
      w->left[ax] = n - 1 - index[ax];
    } else if (d[ax] < 0) {
      index[ax] = std::clamp(static_cast<int>(std::ceil(u)) - 1, 0, n - 1);
      w->next[ax] = (lower_mm_[ax] + index[ax] * s - p0[ax]) / d[ax];
      w->delta[ax] = -s / d[ax];
      w->offset_step[ax] = -stride[ax];
      w->left[ax] = index[ax];
    } else {
      index[ax] = std::clamp(static_cast<int>(std::floor(u)), 0, n - 1);
      w->next[ax] = std::numeric_limits<double>::infinity();
      w->delta[ax] = 0;
      w->offset_step[ax] = 0;
      w->left[ax] = 0;
    }
  }
  w->offset = index[0] + stride[1] * index[1] + stride[2] * index[2];
  w->length = d.norm();
  return true;
}

double GridRayCaster::siddon(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1) const {
  detail::SiddonWalk w;
  if (!start_walk(p0, p1, &w)) return 0.0;
  double a = w.a;
  const double a_end = w.a_end;
  const double* next = w.next;
  const double* delta = w.delta;
  const int* left = w.left;
  const std::ptrdiff_t* offset_step = w.offset_step;
  const Eigen::Vector3d d_rate = (p1 - p0).cwiseAbs().cwiseQuotient(volume_.geometry.spacing_mm);

  // Walk voxel by voxel: each step ends at the nearest plane crossing. Where two crossings
  // coincide (the ray passes through an edge) the next step has zero length. The axes are
  // ordered so that p and q are crossed most often and r least (for CT rays usually the slice
  // axis): the common step chooses between p and q with selects, not branches (which of them
  // comes next is unpredictable: branching on it cost three times as much), and an r crossing
  // is the rare branch. `left_*` counts the planes still inside the volume, so a crossing that
  // rounding places before a_end can never step outside it.
  int order[3] = {0, 1, 2};  // by crossings per unit of a, most first
  std::sort(order, order + 3, [&](int i, int j) { return d_rate[i] > d_rate[j]; });
  const int P = order[0], Q = order[1], R = order[2];
  const float* mu = volume_.values.data();
  std::ptrdiff_t offset = w.offset;
  double np = next[P], nq = next[Q], nr = next[R];
  const double dp = delta[P], dq = delta[Q], dr = delta[R];
  const std::ptrdiff_t op = offset_step[P], oq = offset_step[Q], orr = offset_step[R];
  int left_p = left[P], left_q = left[Q], left_r = left[R];
  double sum = 0.0;
  for (;;) {
    const bool p_first = np <= nq;
    const double n_pq = p_first ? np : nq;
    if (n_pq <= nr) [[likely]] {
      if (n_pq >= a_end) break;
      sum += static_cast<double>(mu[offset]) * (n_pq - a);
      a = n_pq;
      offset += p_first ? op : oq;
      np = p_first ? np + dp : np;
      nq = p_first ? nq : nq + dq;
      left_p -= p_first;
      left_q -= !p_first;
      if ((left_p | left_q) < 0) return sum * w.length;
    } else {
      if (nr >= a_end) break;
      sum += static_cast<double>(mu[offset]) * (nr - a);
      a = nr;
      offset += orr;
      nr += dr;
      if (--left_r < 0) return sum * w.length;
    }
  }
  sum += static_cast<double>(mu[offset]) * (a_end - a);
  return sum * w.length;
}

namespace {

// The lane kernel this CPU runs for `lanes`, or none.
using LaneKernel = void (*)(const float*, const detail::SiddonWalk*, double*);
LaneKernel lane_kernel(SiddonLanes lanes) {
  static const bool avx512 = detail::siddon_avx512_available(), avx2 = detail::siddon_avx2_available();
  switch (lanes) {
    case SiddonLanes::kBest:
      return avx512 ? &detail::siddon_walk_avx512 : avx2 ? &detail::siddon_walk_avx2 : nullptr;
    case SiddonLanes::kAvx2:
      return avx2 ? &detail::siddon_walk_avx2 : nullptr;
    case SiddonLanes::kNone:
      break;
  }
  return nullptr;
}

}  // namespace

bool GridRayCaster::siddon_lanes_available(SiddonLanes lanes) {
  return lane_kernel(lanes) != nullptr;
}

void GridRayCaster::siddon_batch(std::span<const Eigen::Vector3d> from, std::span<const Eigen::Vector3d> to,
                                 std::span<double> integrals, SiddonLanes lanes) const {
  const std::size_t n = std::min({from.size(), to.size(), integrals.size()});
  std::size_t i = 0;
  const LaneKernel kernel = lane_kernel(lanes);
  if (kernel && !volume_.values.empty()) {
    constexpr int kLanes = detail::kSiddonLanes;
    for (; i + kLanes <= n; i += kLanes) {
      detail::SiddonWalk walks[kLanes];
      bool hit[kLanes];
      for (int k = 0; k < kLanes; ++k) hit[k] = start_walk(from[i + k], to[i + k], &walks[k]);
      // A missed ray keeps the default walk: an empty range at voxel 0, summing nothing.
      kernel(volume_.values.data(), walks, &integrals[i]);
      for (int k = 0; k < kLanes; ++k) {
        if (!hit[k]) integrals[i + k] = 0.0;
      }
    }
  }
  for (; i < n; ++i) integrals[i] = siddon(from[i], to[i]);
}

namespace {

// Sum of trilinear samples along a clipped ray, in voxel-index coordinates.
LFTRACK_HOT_CLONES
double trilinear_sum(const float* mu, int nx, int ny, int nz, double x, double y, double z, double dx,
                     double dy, double dz, int samples) {
  const std::ptrdiff_t sy = nx, sz = std::ptrdiff_t{nx} * ny;
  const double max_x = nx - 1, max_y = ny - 1, max_z = nz - 1;
  double sum = 0.0;
  for (int k = 0; k < samples; ++k) {
    const double px = std::clamp(x + k * dx, 0.0, max_x);
    const double py = std::clamp(y + k * dy, 0.0, max_y);
    const double pz = std::clamp(z + k * dz, 0.0, max_z);
    const int ix = std::min(static_cast<int>(px), std::max(nx - 2, 0));
    const int iy = std::min(static_cast<int>(py), std::max(ny - 2, 0));
    const int iz = std::min(static_cast<int>(pz), std::max(nz - 2, 0));
    const double fx = px - ix, fy = py - iy, fz = pz - iz;
    const int ox = nx > 1 ? 1 : 0;
    const std::ptrdiff_t oy = ny > 1 ? sy : 0, oz = nz > 1 ? sz : 0;
    const float* c = mu + ix + sy * iy + sz * iz;
    const double c00 = c[0] + fx * (c[ox] - c[0]);
    const double c10 = c[oy] + fx * (c[oy + ox] - c[oy]);
    const double c01 = c[oz] + fx * (c[oz + ox] - c[oz]);
    const double c11 = c[oz + oy] + fx * (c[oz + oy + ox] - c[oz + oy]);
    const double c0 = c00 + fy * (c10 - c00);
    const double c1 = c01 + fy * (c11 - c01);
    sum += c0 + fz * (c1 - c0);
  }
  return sum;
}

}  // namespace

double GridRayCaster::trilinear(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1, double step_mm) const {
  double a0 = 0, a1 = 0;
  if (!clip(p0, p1, &a0, &a1)) return 0.0;
  const Eigen::Vector3d d = p1 - p0;
  const double length_mm = (a1 - a0) * d.norm();
  const int samples = std::max(1, static_cast<int>(std::ceil(length_mm / step_mm - 1e-9)));
  const double da = (a1 - a0) / samples;
  const VolumeGeometry& g = volume_.geometry;
  const Eigen::Vector3d inv_s = g.spacing_mm.cwiseInverse();
  const Eigen::Vector3d start = (p0 + (a0 + 0.5 * da) * d).cwiseProduct(inv_s);
  const Eigen::Vector3d inc = (da * d).cwiseProduct(inv_s);
  const double sum = trilinear_sum(volume_.values.data(), g.size.x(), g.size.y(), g.size.z(), start.x(),
                                   start.y(), start.z(), inc.x(), inc.y(), inc.z(), samples);
  return sum * (length_mm / samples);
}

}  // namespace lftrack::tracking
