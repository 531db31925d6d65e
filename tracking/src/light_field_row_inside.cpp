// Whether a whole row, or block of rows, of pixel rays lies inside a light field
// (light_field_kernels.hpp, row_inside_field and rows_inside_field): the kernels' per-pixel
// field test, made once per row or block where it cannot fail.
//
// The kernels compute each ray's sample coordinates in float from float constants:
// f_a = base_a + gain_a * q, q = (e0 + e1 c) / (n0 + n1 c). Here the end rays are evaluated in
// double, and the field must hold them with a margin of about 170 float epsilons of
// every term that enters the float computation (each of the kernel's roundings is at most half
// an epsilon of one of them). A row near the field's edge, or one that fails, keeps the
// per-pixel test; the result is the same mask either way.

#include <algorithm>
#include <cmath>

#include "light_field_kernels.hpp"

namespace lftrack::tracking {

bool row_inside_field(const LightFieldGeometry& g, const RayMap& m, int r, int cols) {
  return rows_inside_field(g, m, r, r, cols);
}

// A block of rows, from its four corner rays (a row: its two end rays). Along a row q = (e0 + e1
// c) / (n0 + n1 c) is monotonic where n keeps its sign, so a row's end rays bound it. Over a
// block each term is bounded by its corners: n and e are affine in (r, c), so |e0| + |e1| (cols -
// 1) and the n size are largest at the first or last row (convex), the smallest n is at a corner
// (n > 0 throughout), and q = e / n, linear-fractional over the rectangle, takes its extremes at
// the corners. A block that passes therefore passes row by row.
bool rows_inside_field(const LightFieldGeometry& g, const RayMap& m, int r_first, int r_last, int cols) {
  if (cols < 1 || r_last < r_first) return false;
  constexpr double kRelative = 1e-5;  // about 170 float epsilons
  const double last = double(cols - 1);
  const Eigen::Vector3d d_rows[2] = {m.d00 + m.d_row * r_first, m.d00 + m.d_row * r_last};
  const int ends = r_first == r_last ? 1 : 2;  // a single row is its own last
  const double n1 = m.d_col.dot(g.axis);
  double n_corner[4] = {0, 0, 0, 0};
  double n_min = INFINITY, n_size = 0;
  for (int i = 0; i < ends; ++i) {
    const double n0 = d_rows[i].dot(g.axis);
    n_corner[2 * i] = n0;
    n_corner[2 * i + 1] = n0 + n1 * last;
    n_min = std::min({n_min, n_corner[2 * i], n_corner[2 * i + 1]});
    n_size = std::max(n_size, std::abs(n0) + std::abs(n1) * last);
  }
  // min and max pass a NaN over: each corner's n is tested finite here, each q and margin below.
  for (const double n : n_corner)
    if (!std::isfinite(n)) return false;
  // Every ray runs towards the planes.
  if (!(n_min > 1e-3 * n_size)) return false;
  const Eigen::Vector3d* const e_axes[2] = {&g.e1, &g.e2};
  for (int k = 0; k < 2; ++k) {
    const double e1 = m.d_col.dot(*e_axes[k]);
    double q_lo = INFINITY, q_hi = -INFINITY, e_size = 0;
    for (int i = 0; i < ends; ++i) {
      const double e0 = d_rows[i].dot(*e_axes[k]);
      e_size = std::max(e_size, std::abs(e0) + std::abs(e1) * last);
      for (const double q : {e0 / n_corner[2 * i], (e0 + e1 * last) / n_corner[2 * i + 1]}) {
        if (!std::isfinite(q)) return false;
        q_lo = std::min(q_lo, q);
        q_hi = std::max(q_hi, q);
      }
    }
    const double q_max = std::max(std::abs(q_lo), std::abs(q_hi));
    // q's error: of its numerator and denominator, relative to the smallest denominator.
    const double dq = kRelative * (e_size + q_max * n_size) / n_min;
    for (const int a : {k, k + 2}) {  // q1 maps to u and s, q2 to v and t
      const double gain = m.gain[a], base = m.base[a];
      const double lo = std::min(gain * q_lo, gain * q_hi) + base;
      const double hi = std::max(gain * q_lo, gain * q_hi) + base;
      const double margin = std::abs(gain) * dq + kRelative * (std::abs(gain) * q_max + std::abs(base) + 1.0);
      if (!std::isfinite(margin) || !(lo >= margin && hi <= double(m.limit[a]) - margin)) return false;
    }
  }
  return true;
}

}  // namespace lftrack::tracking
