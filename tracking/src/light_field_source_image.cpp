// A render's source image (light_field_kernels.hpp): the field blended in (u, v) once per (s, t)
// sample, for the renderer's source-image path.
//
// Why: a pixel's quadrilinear blend reads 16 samples, four (s, t) neighbours in each of four
// (u, v) cells. The source plane and the (s, t) plane are parallel, so the (u, v) of the ray
// from the moved source S' through an (s, t) point is affine in it: u = base_u + (s - base_s)
// * gain_u / gain_s, and likewise v with t. Where S' sits on the source plane (the nominal pose)
// every ray has the same (u, v); a pose inside the envelope moves S' off the plane by a few mm
// of the roughly 1,500 mm to the ROI, so across a whole window (u, v) moves by a small fraction
// of a sample. Blending each (s, t) sample of the window's footprint once, at its own ray's
// (u, v), leaves four reads a pixel; a window reads about as many (s, t) samples as it has
// pixels, so the blend costs a fraction of what it saves.

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "cpu_dispatch.hpp"
#include "light_field_kernels.hpp"

namespace lftrack::tracking {
namespace {

#define LFTRACK_INLINE inline __attribute__((always_inline))

// The (u, v) of the rays through the image's (s, t) samples: u = u_at_s0 + u_per_s * i on image
// row i, v = v_at_t0 + v_per_t * j on image column j (sample units).
struct UvAlongSt {
  double u_at_s0, u_per_s, v_at_t0, v_per_t;
};

UvAlongSt uv_along_st(const RayMap& m, const SourceImage& image) {
  // s = base_s + gain_s q1 and u = base_u + gain_u q1 (likewise t, v with q2).
  const double u_per_s = double(m.gain[0]) / double(m.gain[2]), v_per_t = double(m.gain[1]) / double(m.gain[3]);
  return {double(m.base[0]) + u_per_s * (image.s0 - double(m.base[2])), u_per_s,
          double(m.base[1]) + v_per_t * (image.t0 - double(m.base[3])), v_per_t};
}

// Columns [j_begin, j_end) of one image row: sample (s, t0 + j) of the four (u, v) cells around
// (u, v_j), blended, times `scale`, into out[j - j_begin]. `Load` reads a sample as a float at an
// offset into the field. A column's value does not depend on the range it is blended in.
template <class Load>
LFTRACK_INLINE void blend_row(const Load& load, const LightFieldGeometry& g, std::size_t row_offset, float cu,
                              double v_at_t0, double v_per_t, float scale, int j_begin, int j_end, float* out) {
  const std::size_t su = std::size_t(g.size[1]) * g.size[2] * g.size[3], sv = std::size_t(g.size[2]) * g.size[3];
  const int top_u = g.size[0] - 2, top_v = g.size[1] - 2;
  const float limit_v = float(g.size[1] - 1);
  const int iu = std::min(int(cu), top_u);
  const float wu = cu - float(iu);
  const std::size_t u_offset = row_offset + std::size_t(iu) * su;
  const float fv0 = float(v_at_t0), dv = float(v_per_t);
  const auto cv_at = [&](int j) { return std::clamp(fv0 + dv * float(j), 0.0f, limit_v); };
  const auto v_cell = [&](float cv) { return std::min(int(cv), top_v); };
  const int iv_first = v_cell(cv_at(j_begin)), iv_last = v_cell(cv_at(j_end - 1));
  out -= j_begin;
  if (iv_first == iv_last) {
    // One (u, v) cell for the whole range (nearly always): four streams, vectorised.
    const std::size_t p00 = u_offset + std::size_t(iv_first) * sv, p01 = p00 + sv, p10 = p00 + su, p11 = p10 + sv;
    const float ivf = float(iv_first);
    for (int j = j_begin; j < j_end; ++j) {
      const float wv = cv_at(j) - ivf;
      const float a = load(p00 + std::size_t(j)), b = load(p01 + std::size_t(j));
      const float c = load(p10 + std::size_t(j)), d = load(p11 + std::size_t(j));
      const float low = a + wv * (b - a), high = c + wv * (d - c);
      out[j] = (low + wu * (high - low)) * scale;
    }
    return;
  }
  for (int j = j_begin; j < j_end; ++j) {
    const float cv = cv_at(j);
    const int iv = v_cell(cv);
    const float wv = cv - float(iv);
    const std::size_t p00 = u_offset + std::size_t(iv) * sv + std::size_t(j), p10 = p00 + su;
    const float a = load(p00), b = load(p00 + sv), c = load(p10), d = load(p10 + sv);
    const float low = a + wv * (b - a), high = c + wv * (d - c);
    out[j] = (low + wu * (high - low)) * scale;
  }
}

// Image row i's columns [j_begin, j_end), blended into out.
template <class Load>
LFTRACK_INLINE void blend_image_row(const Load& load, float scale, const LightFieldGeometry& g, const UvAlongSt& uv,
                                    const SourceImage& image, int i, int j_begin, int j_end, float* out) {
  const float cu = std::clamp(float(uv.u_at_s0 + uv.u_per_s * i), 0.0f, float(g.size[0] - 1));
  const std::size_t row_offset = std::size_t(image.s0 + i) * std::size_t(g.size[3]) + std::size_t(image.t0);
  blend_row(load, g, row_offset, cu, uv.v_at_t0, uv.v_per_t, scale, j_begin, j_end, out);
}

template <class Load>
LFTRACK_INLINE void blend_rows(const Load& load, float scale, const LightFieldGeometry& g, const RayMap& m,
                               const SourceImage& image, int i_begin, int i_end) {
  const UvAlongSt uv = uv_along_st(m, image);
  for (int i = i_begin; i < i_end; ++i)
    blend_image_row(load, scale, g, uv, image, i, 0, image.cols,
                    image.values + std::size_t(i) * std::size_t(image.cols));
}

// Pair rows [i_begin, i_end): image rows i_begin .. i_end, each blended once, a block of columns
// at a time into two row buffers on the stack, each row interleaved with the one below it.
template <class Load>
LFTRACK_INLINE void blend_pair_rows(const Load& load, float scale, const LightFieldGeometry& g, const RayMap& m,
                                    const SourceImage& image, int i_begin, int i_end) {
  if (i_begin >= i_end) return;
  const UvAlongSt uv = uv_along_st(m, image);
  constexpr int kBlock = 256;
  float rows[2][kBlock];
  for (int j_begin = 0; j_begin < image.cols; j_begin += kBlock) {
    const int j_end = std::min(image.cols, j_begin + kBlock), n = j_end - j_begin;
    float* above = rows[0];
    float* below = rows[1];
    blend_image_row(load, scale, g, uv, image, i_begin, j_begin, j_end, above);
    for (int i = i_begin; i < i_end; ++i) {
      blend_image_row(load, scale, g, uv, image, i + 1, j_begin, j_end, below);
      float* pair = image.pairs + 2 * (std::size_t(i) * std::size_t(image.cols) + std::size_t(j_begin));
      for (int j = 0; j < n; ++j) {
        pair[2 * j] = above[j];
        pair[2 * j + 1] = below[j];
      }
      std::swap(above, below);
    }
  }
}

struct FloatLoad {
  const float* f;
  LFTRACK_INLINE float operator()(std::size_t i) const { return f[i]; }
};
struct Fixed16Load {
  const std::uint16_t* q;
  LFTRACK_INLINE float operator()(std::size_t i) const { return float(q[i]); }
};

}  // namespace

bool source_image_box(const LightFieldGeometry& g, const RayMap& m, int rows, int cols, long max_samples,
                      SourceImage* box) {
  // Rays must run from the source towards the (s, t) plane (gain_s, gain_t > 0: the ROI lies
  // ahead of the moved source), and (u, v) must be affine in (s, t) with finite slopes.
  if (rows < 1 || cols < 1 || !(m.gain[2] > 0) || !(m.gain[3] > 0) || !std::isfinite(m.gain[0]) ||
      !std::isfinite(m.gain[1]) || !std::isfinite(m.gain[2]) || !std::isfinite(m.gain[3]))
    return false;
  for (int a = 0; a < 4; ++a)
    if (!std::isfinite(m.base[a])) return false;
  // The blend steps (u, v) along the image in float (uv_along_st): a slope that overflows a float
  // would make NaN coordinates there, and NaN cells.
  if (!std::isfinite(float(double(m.gain[0]) / double(m.gain[2]))) ||
      !std::isfinite(float(double(m.gain[1]) / double(m.gain[3]))))
    return false;
  // The window's rays meet the (s, t) plane inside the quadrilateral of its corner rays (a plane
  // maps to a plane projectively; d.n is affine in the pixel, so positive at the corners means
  // positive throughout).
  double s_min = INFINITY, s_max = -INFINITY, t_min = INFINITY, t_max = -INFINITY;
  for (int r : {0, rows - 1})
    for (int c : {0, cols - 1}) {
      const Eigen::Vector3d d = m.d00 + m.d_row * double(r) + m.d_col * double(c);
      const double dn = d.dot(g.axis);
      if (!(dn > 0)) return false;
      const double s = m.base[2] + m.gain[2] * (d.dot(g.e1) / dn), t = m.base[3] + m.gain[3] * (d.dot(g.e2) / dn);
      if (!std::isfinite(s) || !std::isfinite(t)) return false;
      s_min = std::min(s_min, s), s_max = std::max(s_max, s);
      t_min = std::min(t_min, t), t_max = std::max(t_max, t);
    }
  // A sample's margin on each side for the kernels' float rounding; clamped to the field.
  const auto first = [](double lo, int size) { return int(std::clamp(std::floor(lo) - 1, 0.0, double(size - 1))); };
  const auto last = [](double hi, int size) { return int(std::clamp(std::floor(hi) + 2, 0.0, double(size - 1))); };
  const int s0 = first(s_min, g.size[2]), s1 = last(s_max, g.size[2]);
  const int t0 = first(t_min, g.size[3]), t1 = last(t_max, g.size[3]);
  // Rays that all miss the field leave a box under two samples wide: the per-ray kernels mask them.
  if (s1 - s0 < 1 || t1 - t0 < 1 || s_max < 0 || t_max < 0 || s_min > g.size[2] - 1 || t_min > g.size[3] - 1)
    return false;
  const long samples = long(s1 - s0 + 1) * long(t1 - t0 + 1);
  if (samples > max_samples) return false;
  box->s0 = s0;
  box->t0 = t0;
  box->rows = s1 - s0 + 1;
  box->cols = t1 - t0 + 1;
  return true;
}

LFTRACK_HOT_CLONES
void blend_source_image_float(const float* samples, const LightFieldGeometry& g, const RayMap& m,
                              const SourceImage& image, int i_begin, int i_end) {
  blend_rows(FloatLoad{samples}, 1.0f, g, m, image, i_begin, i_end);
}

LFTRACK_HOT_CLONES
void blend_source_image_fixed16(const std::uint16_t* codes, float scale, const LightFieldGeometry& g, const RayMap& m,
                                const SourceImage& image, int i_begin, int i_end) {
  blend_rows(Fixed16Load{codes}, scale, g, m, image, i_begin, i_end);
}

LFTRACK_HOT_CLONES
void blend_source_image_pairs_float(const float* samples, const LightFieldGeometry& g, const RayMap& m,
                                    const SourceImage& image, int i_begin, int i_end) {
  blend_pair_rows(FloatLoad{samples}, 1.0f, g, m, image, i_begin, i_end);
}

LFTRACK_HOT_CLONES
void blend_source_image_pairs_fixed16(const std::uint16_t* codes, float scale, const LightFieldGeometry& g,
                                      const RayMap& m, const SourceImage& image, int i_begin, int i_end) {
  blend_pair_rows(Fixed16Load{codes}, scale, g, m, image, i_begin, i_end);
}

}  // namespace lftrack::tracking
