// The light-field renderer: for each pixel, the ray from the (moved) source through the pixel is
// intersected with the two planes and the 16 surrounding samples are blended quadrilinearly.
//
// By default (RendererOptions::light_field_source_image) float and 16-bit fields take a shorter
// way to nearly the same blend: the (u, v) part is done once per (s, t) sample of the window's
// footprint, at that sample's own ray, into a per-render "source image"
// (light_field_source_image.cpp explains why that works), and each pixel then reads its four (s, t)
// neighbours from it. Where the image does not suit (source_image_box), the per-ray kernels below
// render.
//
// Per render, everything is moved into the CT frame once. A pixel's ray direction d is affine in
// (row, col); with q1 = d.e1 / d.n and q2 = d.e2 / d.n (one division per pixel) the four ray
// coordinates are affine in (q1, q2), so the inner loop is a handful of multiply-adds, one
// division and 16 loads. Float and 16-bit fields use the AVX-512 kernels
// (light_field_kernel_avx512.cpp, sixteen pixels at a time and mostly without gathers) or the
// AVX2 kernels (light_field_kernel_avx2.cpp) where the CPU has them; the scalar kernels below serve VQ fields
// and other CPUs. (GCC 12 does not vectorise the scalar loop itself: it sinks the blend into a branch on the
// field test.)
//
// Coarse pixels (a registration's 4 x 4 and 8 x 8 binned levels) read a copy of the field averaged over 2 x 2
// or 4 x 4 (s, t) samples (LightField::downsampled_st, light_field_mip.cpp), chosen by the pixel's
// footprint at the window's centre at the nominal pose: the pixel then averages rays over about
// its footprint (a box of the copy's spacing, interpolated), as a binned detector pixel averages,
// and its samples are 1/4 or 1/16 as many. The fields' (s, t) slices (256 KB
// each on the lumbar CT) otherwise miss the caches when a coarse row steps several samples per
// pixel: on the lumbar CT a 4 x 4 binned window rendered in about 100 us, now about 30 us
// (BENCHMARKS.md, "Tracking at 30 Hz").

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <memory>
#include <vector>

#include "cpu_dispatch.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "light_field_kernels.hpp"
#include "scratch_buffers.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

// The kernel's helpers must inline into the pixel loop (GCC otherwise keeps calls there).
#define LFTRACK_INLINE inline __attribute__((always_inline))

struct FloatFetch {
  const float* f;
  std::size_t stride_u, stride_v, stride_s;
  LFTRACK_INLINE float operator()(std::size_t base, int is, int it) const {
    return f[base + std::size_t(is) * stride_s + std::size_t(it)];
  }
  LFTRACK_INLINE std::size_t uv(int iu, int iv) const {
    return std::size_t(iu) * stride_u + std::size_t(iv) * stride_v;
  }
};

struct Fixed16Fetch {
  const std::uint16_t* q;
  float scale;
  std::size_t stride_u, stride_v, stride_s;
  LFTRACK_INLINE float operator()(std::size_t base, int is, int it) const {
    return float(q[base + std::size_t(is) * stride_s + std::size_t(it)]) * scale;
  }
  LFTRACK_INLINE std::size_t uv(int iu, int iv) const {
    return std::size_t(iu) * stride_u + std::size_t(iv) * stride_v;
  }
};

struct VqFetch {
  const float* codebook;
  const std::uint16_t* codes;
  std::size_t tiles_v, tiles_s, tiles_t;
  // `base` packs the (u, v) tile offset and the (u, v) element bits.
  LFTRACK_INLINE float operator()(std::size_t base, int is, int it) const {
    const std::size_t tile = (base >> 4) + std::size_t(is >> 1) * tiles_t + std::size_t(it >> 1);
    const std::size_t element = (base & 15u) | (std::size_t(is & 1) << 1) | std::size_t(it & 1);
    return codebook[std::size_t(codes[tile]) * 16 + element];
  }
  LFTRACK_INLINE std::size_t uv(int iu, int iv) const {
    const std::size_t tile = (std::size_t(iu >> 1) * tiles_v + std::size_t(iv >> 1)) * tiles_s * tiles_t;
    return (tile << 4) | (std::size_t(iu & 1) << 3) | (std::size_t(iv & 1) << 2);
  }
};

template <class Fetch>
LFTRACK_INLINE float bilinear_st(const Fetch& fetch, std::size_t base, int is, int it, float ws, float wt) {
  const float a = fetch(base, is, it), b = fetch(base, is, it + 1);
  const float c = fetch(base, is + 1, it), d = fetch(base, is + 1, it + 1);
  const float top = a + wt * (b - a), bottom = c + wt * (d - c);
  return top + ws * (bottom - top);
}

// The papers' blend: the 16 samples around (u, v, s, t), quadrilinearly.
template <class Fetch>
struct Quadrilinear {
  Fetch fetch;
  int top_u, top_v, top_s, top_t;  // size - 2 per axis
  Quadrilinear(const Fetch& f, const LightFieldGeometry& g)
      : fetch(f), top_u(g.size[0] - 2), top_v(g.size[1] - 2), top_s(g.size[2] - 2), top_t(g.size[3] - 2) {}
  // Coordinates inside the field (clamped by the caller).
  LFTRACK_INLINE float operator()(float cu, float cv, float cs, float ct) const {
    const int iu = std::min(int(cu), top_u), iv = std::min(int(cv), top_v);
    const int is = std::min(int(cs), top_s), it = std::min(int(ct), top_t);
    const float wu = cu - float(iu), wv = cv - float(iv), ws = cs - float(is), wt = ct - float(it);
    const float s00 = bilinear_st(fetch, fetch.uv(iu, iv), is, it, ws, wt);
    const float s01 = bilinear_st(fetch, fetch.uv(iu, iv + 1), is, it, ws, wt);
    const float s10 = bilinear_st(fetch, fetch.uv(iu + 1, iv), is, it, ws, wt);
    const float s11 = bilinear_st(fetch, fetch.uv(iu + 1, iv + 1), is, it, ws, wt);
    const float low = s00 + wv * (s01 - s00), high = s10 + wv * (s11 - s10);
    return low + wu * (high - low);
  }
};

// A render's source image (light_field_kernels.hpp), bilinearly in (s, t): (u, v) were blended
// into it. Indices are clamped into the image, which holds every inside pixel's neighbours.
struct SourceImageBilinear {
  SourceImage image;
  LFTRACK_INLINE float operator()(float, float, float cs, float ct) const {
    const int is = std::clamp(int(cs) - image.s0, 0, image.rows - 2);
    const int it = std::clamp(int(ct) - image.t0, 0, image.cols - 2);
    const float ws = cs - float(is + image.s0), wt = ct - float(it + image.t0);
    const float* row = image.values + std::size_t(is) * std::size_t(image.cols) + std::size_t(it);
    const float* next = row + image.cols;
    const float top = row[0] + wt * (row[1] - row[0]), bottom = next[0] + wt * (next[1] - next[0]);
    return top + ws * (bottom - top);
  }
};

// Renders rows [r_begin, r_end) of the window; returns the number of masked pixels. The column
// loop is straight-line code (coordinates clamped into the field, the out-of-field test applied
// as a select at the end) so that the compiler can vectorise it with gathers.
template <bool kWithMask, class Sampler>
LFTRACK_INLINE int render_rows_impl(const Sampler& sample, const RayMap& m, const LightFieldGeometry& g,
                                    ImageView<float> out, ImageView<unsigned char> valid, int cols,
                                    int r_begin, int r_end) {
  int masked = 0;
  const Vector3d& n = g.axis;
  for (int r = r_begin; r < r_end; ++r) {
    const Vector3d d_row = m.d00 + m.d_row * r;
    // d.n, d.e1, d.e2 are affine in the column.
    const float dn0 = float(d_row.dot(n)), dn1 = float(m.d_col.dot(n));
    const float de10 = float(d_row.dot(g.e1)), de11 = float(m.d_col.dot(g.e1));
    const float de20 = float(d_row.dot(g.e2)), de21 = float(m.d_col.dot(g.e2));
    float* dst = out.row_ptr(r);
    unsigned char* ok_row = kWithMask ? valid.row_ptr(r) : nullptr;
    int row_masked = 0;
    for (int c = 0; c < cols; ++c) {
      const float dn = dn0 + dn1 * float(c);
      const float inv = 1.0f / dn;
      const float q1 = (de10 + de11 * float(c)) * inv, q2 = (de20 + de21 * float(c)) * inv;
      const float fu = m.base[0] + m.gain[0] * q1, fv = m.base[1] + m.gain[1] * q2;
      const float fs = m.base[2] + m.gain[2] * q1, ft = m.base[3] + m.gain[3] * q2;
      // Written so that NaN lands on the outside.
      const bool inside = (dn > 0) & (fu >= 0) & (fu <= m.limit[0]) & (fv >= 0) & (fv <= m.limit[1]) &
                          (fs >= 0) & (fs <= m.limit[2]) & (ft >= 0) & (ft <= m.limit[3]);
      const float cu = inside ? fu : 0.0f, cv = inside ? fv : 0.0f, cs = inside ? fs : 0.0f,
                  ct = inside ? ft : 0.0f;
      const float value = sample(cu, cv, cs, ct);
      // Multiplying (not selecting) keeps the interpolation unconditional, so it is not sunk
      // into a branch; outside the field the clamped coordinates read finite samples, so the
      // product is an exact 0.
      const float keep = inside ? 1.0f : 0.0f;
      dst[c] = value * keep;
      row_masked += static_cast<int>(1.0f - keep);
      if constexpr (kWithMask) ok_row[c] = static_cast<unsigned char>(keep);
    }
    masked += row_masked;
  }
  return masked;
}

// The mask store is a template parameter so that neither loop has a branch in it.
template <class Sampler>
LFTRACK_INLINE int render_rows(const Sampler& sample, const RayMap& m, const LightFieldGeometry& g,
                               ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin,
                               int r_end) {
  return valid.data ? render_rows_impl<true>(sample, m, g, out, valid, cols, r_begin, r_end)
                    : render_rows_impl<false>(sample, m, g, out, valid, cols, r_begin, r_end);
}

LFTRACK_HOT_CLONES
int render_float(const FloatFetch& f, const RayMap& m, const LightFieldGeometry& g, ImageView<float> out,
                 ImageView<unsigned char> valid, int cols, int r0, int r1) {
  return render_rows(Quadrilinear<FloatFetch>(f, g), m, g, out, valid, cols, r0, r1);
}
LFTRACK_HOT_CLONES
int render_fixed16(const Fixed16Fetch& f, const RayMap& m, const LightFieldGeometry& g, ImageView<float> out,
                   ImageView<unsigned char> valid, int cols, int r0, int r1) {
  return render_rows(Quadrilinear<Fixed16Fetch>(f, g), m, g, out, valid, cols, r0, r1);
}
LFTRACK_HOT_CLONES
int render_vq(const VqFetch& f, const RayMap& m, const LightFieldGeometry& g, ImageView<float> out,
              ImageView<unsigned char> valid, int cols, int r0, int r1) {
  return render_rows(Quadrilinear<VqFetch>(f, g), m, g, out, valid, cols, r0, r1);
}

// A view's fields: the field as built, and its (s, t)-averaged copies by 2 and 4 (absent where
// the renderer makes none or the field is too small for them).
struct FieldLevels {
  std::shared_ptr<const LightField> field;
  std::array<std::shared_ptr<const LightField>, 2> averaged;  // by 2, by 4
};

// The ray map of `field` for the pixels of `window` at the moved source.
RayMap ray_map(const LightFieldGeometry& g, const Vector3d& source, const Vector3d& d00, const Vector3d& d_row,
               const Vector3d& d_col) {
  RayMap m;
  m.d00 = d00;
  m.d_row = d_row;
  m.d_col = d_col;
  // u = (S'-S).e1 + ((S-S').n) q1, s = (S'-C).e1 + ((C-S').n) q1; likewise v, t with e2, q2.
  const double k_uv = (g.source_ct_mm - source).dot(g.axis), k_st = (g.roi_centre_ct_mm - source).dot(g.axis);
  const double offset[4] = {(source - g.source_ct_mm).dot(g.e1), (source - g.source_ct_mm).dot(g.e2),
                            (source - g.roi_centre_ct_mm).dot(g.e1), (source - g.roi_centre_ct_mm).dot(g.e2)};
  const double gain[4] = {k_uv, k_uv, k_st, k_st};
  for (int a = 0; a < 4; ++a) {
    m.base[a] = float((offset[a] - g.lo[a]) / g.spacing(a));
    m.gain[a] = float(gain[a] / g.spacing(a));
    m.limit[a] = float(g.size[a] - 1);
  }
  return m;
}

// How many (s, t) samples of the map's field one pixel spans, on the narrower of the two axes:
// at the window's centre pixel, the change of the sample coordinates s and t over one row and
// one column.
double pixel_footprint_samples(const RayMap& m, const LightFieldGeometry& g, int rows, int cols) {
  const auto st_at = [&](double r, double c) {
    const Vector3d d = m.d00 + m.d_row * r + m.d_col * c;
    const double dn = d.dot(g.axis);
    return Eigen::Vector2d(m.gain[2] * d.dot(g.e1) / dn, m.gain[3] * d.dot(g.e2) / dn);
  };
  const double r = 0.5 * (rows - 1), c = 0.5 * (cols - 1);
  const Eigen::Vector2d centre = st_at(r, c);
  const Eigen::Vector2d along_row = (st_at(r, c + 1) - centre).cwiseAbs();
  const Eigen::Vector2d along_col = (st_at(r + 1, c) - centre).cwiseAbs();
  const Eigen::Vector2d span = along_row + along_col;  // a pixel's extent on s and on t
  return std::isfinite(span.minCoeff()) ? span.minCoeff() : 0.0;
}

// The footprint (pixel_footprint_samples) of the window's pixels at the field's nominal pose.
double nominal_footprint_samples(const LightField::Header& h, const XrayView& view, const PixelWindow& window) {
  const Pose ct_from_room = h.nominal_T_room_from_ct.inverse();
  const Vector3d source = ct_from_room * view.source_mm;
  const RayMap m = ray_map(h.geometry, source, ct_from_room * view.pixel_centre_mm(window.row0, window.col0) - source,
                           ct_from_room.linear() * view.row_axis * view.pitch_row_mm,
                           ct_from_room.linear() * view.col_axis * view.pitch_col_mm);
  return pixel_footprint_samples(m, h.geometry, window.rows, window.cols);
}

class LightFieldRenderer final : public DrrRenderer {
 public:
  LightFieldRenderer(std::vector<FieldLevels> fields, ThreadPool* pool, SimdLevel simd, bool source_image)
      : fields_(std::move(fields)), pool_(pool) {
    name_ = std::string("lightfield-") + to_string(fields_.front().field->header().storage);
    bool indexable = true;  // the kernels index samples with 32-bit lanes
    for (const auto& f : fields_)
      indexable = indexable && f.field->geometry().sample_count() < (std::int64_t{1} << 31);
    use_avx512_ = indexable && simd == SimdLevel::kBest && light_field_avx512_available();
    use_avx2_ = indexable && simd != SimdLevel::kScalar && light_field_avx2_available();
    avx2_runs_ = simd != SimdLevel::kAvx2Gathers;
    for (const auto& f : fields_) {
      const auto& size = f.field->geometry().size;
      // The image, or for the AVX2 render its row pairs: two floats a sample.
      image_reserve_ = std::max(image_reserve_, std::size_t(size[2]) * std::size_t(size[3]) * (use_avx2_ ? 2 : 1));
    }
    image_reserve_ = std::min<std::size_t>(image_reserve_, kMaxImageReserve);
    const bool vq = fields_.front().field->header().storage == LightFieldStorage::kVq;
    // One render a pool thread (a registration's candidates), one from the thread that calls
    // the registration, and one from a watcher outside the loop (the monitor's overlay renders
    // with the registration's renderer on the hub's thread: with only one outside the pool, the
    // overlay's render sometimes took the cycle's buffer, and the cycle then allocated one, in
    // ClosedLoop.APageWithTenClientsAndOpenIgtlinkChangeNothingInTheCycle); none for VQ fields,
    // which the source image does not read.
    if (source_image && !vq)
      scratch_ = std::make_unique<ScratchBuffers>((pool_ ? pool_->size() : 1) + 2, image_reserve_);
    if (vq) name_ += std::to_string(fields_.front().field->header().codebook_size);
  }

  std::string_view name() const override { return name_; }
  std::size_t bytes() const override {
    std::size_t total = 0;
    for (const auto& f : fields_) {
      total += f.field->payload_bytes();
      for (const auto& averaged : f.averaged) total += averaged ? averaged->payload_bytes() : 0;
    }
    return total;
  }

 protected:
  Status do_render(const Pose& T_room_from_ct, const XrayView& view, const PixelWindow& window,
                   ImageView<float> out, RenderExtras* extras) const override {
    const FieldLevels* levels = nullptr;
    for (const auto& f : fields_)
      if (f.field->geometry().view_name == view.name) levels = &f;
    if (!levels) return not_found("no light field for view '" + view.name + "'");
    const LightField* field = levels->field.get();
    const LightField::Header& h = field->header();
    if ((h.nominal_T_room_from_ct.inverse() * view.source_mm - h.geometry.source_ct_mm).norm() > 1e-3) {
      return failed_precondition("view '" + view.name + "' has another source position than its light field");
    }
    const PoseDelta delta =
        delta_between(h.nominal_T_room_from_ct, T_room_from_ct, h.registration_origin_room_mm);
    extras->pose_outside_envelope =
        delta.translation_mm.cwiseAbs().maxCoeff() > h.envelope.translation_mm * (1 + 1e-9) + 1e-9 ||
        delta.rotation_rad.cwiseAbs().maxCoeff() > deg_to_rad(h.envelope.rotation_deg) * (1 + 1e-9) + 1e-12;

    // The moved source S' and pixel directions in the CT frame.
    const Pose ct_from_room = T_room_from_ct.inverse();
    const Vector3d source = ct_from_room * view.source_mm;
    const Vector3d d00 = ct_from_room * view.pixel_centre_mm(window.row0, window.col0) - source;
    const Vector3d d_row = ct_from_room.linear() * view.row_axis * view.pitch_row_mm;
    const Vector3d d_col = ct_from_room.linear() * view.col_axis * view.pitch_col_mm;
    // Coarse pixels read the copy averaged over about their footprint (the largest made that fits
    // it), chosen by the footprint at the nominal pose: the same copy for every pose of the view
    // and window, so a registration's cost does not jump between copies as its pose moves.
    int factor = 1;
    const double footprint = nominal_footprint_samples(h, view, window);
    for (int k = int(levels->averaged.size()) - 1; k >= 0 && factor == 1; --k) {
      if (levels->averaged[std::size_t(k)] && footprint >= double(2 << k)) {
        field = levels->averaged[std::size_t(k)].get();
        factor = 2 << k;
      }
    }
    RayMap m = ray_map(field->geometry(), source, d00, d_row, d_col);
    // Rays past the built field's last (s, t) sample stay outside in a copy, as they are there.
    for (int a = 2; a < 4; ++a) m.limit[a] = float(double(h.geometry.size[a] - 1) / double(factor));
    const LightFieldGeometry& g = field->geometry();
    const LightFieldStorage storage = field->header().storage;
    const double fixed_scale = field->header().fixed_scale;

    if (render_from_source_image(g, m, storage, *field, window, out, extras)) return {};
    std::atomic<int> masked{0};
    const auto& s = g.size;
    auto rows = [&](int r0, int r1) {
      int n = 0;
      switch (storage) {
        case LightFieldStorage::kFloat32: {
          if (use_avx512_) {
            n = render_float_avx512(field->float_samples(), g, m, out, extras->valid, window.cols, r0, r1);
            break;
          }
          if (use_avx2_) {
            n = render_float_avx2(field->float_samples(), g, m, out, extras->valid, window.cols, r0, r1, avx2_runs_);
            break;
          }
          const FloatFetch f{field->float_samples(), std::size_t(s[1]) * s[2] * s[3],
                             std::size_t(s[2]) * s[3], std::size_t(s[3])};
          n = render_float(f, m, g, out, extras->valid, window.cols, r0, r1);
          break;
        }
        case LightFieldStorage::kFixed16: {
          if (use_avx512_) {
            n = render_fixed16_avx512(field->fixed_samples(), float(fixed_scale), g, m, out, extras->valid,
                                      window.cols, r0, r1);
            break;
          }
          if (use_avx2_) {
            n = render_fixed16_avx2(field->fixed_samples(), float(fixed_scale), g, m, out, extras->valid,
                                    window.cols, r0, r1, avx2_runs_);
            break;
          }
          const Fixed16Fetch f{field->fixed_samples(), float(fixed_scale), std::size_t(s[1]) * s[2] * s[3],
                               std::size_t(s[2]) * s[3], std::size_t(s[3])};
          n = render_fixed16(f, m, g, out, extras->valid, window.cols, r0, r1);
          break;
        }
        case LightFieldStorage::kVq: {
          if (use_avx512_) {
            n = render_vq_avx512(field->codebook(), field->tile_codes(), g, m, out, extras->valid,
                                 window.cols, r0, r1);
            break;
          }
          const VqFetch f{field->codebook(), field->tile_codes(), std::size_t(s[1] + 1) / 2,
                          std::size_t(s[2] + 1) / 2, std::size_t(s[3] + 1) / 2};
          n = render_vq(f, m, g, out, extras->valid, window.cols, r0, r1);
          break;
        }
      }
      masked.fetch_add(n, std::memory_order_relaxed);
    };
    if (pool_)
      pool_->parallel_for(window.rows, 8, rows);
    else
      rows(0, window.rows);
    extras->masked_pixels = masked.load();
    return {};
  }

 private:
  // The source-image path (light_field_kernels.hpp) for float and 16-bit fields; false where
  // it does not suit (source_image_box), and the per-ray kernels render instead.
  bool render_from_source_image(const LightFieldGeometry& g, const RayMap& m, LightFieldStorage storage,
                                const LightField& field, const PixelWindow& window, ImageView<float> out,
                                RenderExtras* extras) const {
    if (!scratch_) return false;  // the source image is off, or the fields are VQ
    SourceImage image;
    // A window reads about one (s, t) sample a pixel, or fewer; a box far larger means pixels far
    // coarser than the samples (without an averaged copy), where blending it all would cost more
    // than it saves.
    const long max_samples = std::min(4L * window.rows * window.cols + 4096, kMaxSourceImageSamples);
    if (!source_image_box(g, m, window.rows, window.cols, max_samples, &image)) return false;
    // The AVX2 render reads the image's row pairs, blended straight from the field; the portable
    // one reads the image. The buffer is one of the renderer's own (scratch_), made at
    // construction for the largest field's (s, t) plane, so a render allocates nothing; a larger
    // image (a window over most of a field of more than 2^21 (s, t) samples), or more renders at
    // once than the pool has threads plus one, gets a buffer of its own for the render.
    const std::size_t samples = std::size_t(image.rows) * std::size_t(image.cols);
    const std::size_t needed = use_avx2_ ? 2 * (samples - std::size_t(image.cols)) : samples;
    ScratchBuffers::Lease lease = scratch_->borrow(needed);
    float* const buffer = lease.data();
    (use_avx2_ ? image.pairs : image.values) = buffer;
    const auto blend = [&](int i0, int i1) {
      const bool f32 = storage == LightFieldStorage::kFloat32;
      const float scale = float(field.header().fixed_scale);
      if (use_avx2_ && f32)
        blend_source_image_pairs_float(field.float_samples(), g, m, image, i0, i1);
      else if (use_avx2_)
        blend_source_image_pairs_fixed16(field.fixed_samples(), scale, g, m, image, i0, i1);
      else if (f32)
        blend_source_image_float(field.float_samples(), g, m, image, i0, i1);
      else
        blend_source_image_fixed16(field.fixed_samples(), scale, g, m, image, i0, i1);
    };
    std::atomic<int> masked{0};
    const auto rows = [&](int r0, int r1) {
      const int n = use_avx2_ ? render_source_image_avx2(image, g, m, out, extras->valid, window.cols, r0, r1)
                              : render_source_image(image, g, m, out, extras->valid, window.cols, r0, r1);
      masked.fetch_add(n, std::memory_order_relaxed);
    };
    const int blended_rows = use_avx2_ ? image.rows - 1 : image.rows;  // pair rows, or rows
    if (pool_) {
      // One band of rows a thread: a band of pair rows blends one image row more than it owns.
      pool_->parallel_for(blended_rows, std::max(8, (blended_rows + pool_->size() - 1) / pool_->size()), blend);
      pool_->parallel_for(window.rows, 8, rows);
    } else {
      blend(0, blended_rows);
      rows(0, window.rows);
    }
    extras->masked_pixels = masked.load();
    return true;
  }

  // At most 16 MiB of source image in each of scratch_'s buffers.
  static constexpr std::size_t kMaxImageReserve = std::size_t{1} << 22;

  std::vector<FieldLevels> fields_;
  ThreadPool* pool_;
  std::size_t image_reserve_ = 0;  // floats
  std::unique_ptr<ScratchBuffers> scratch_;  // the source images' buffers; null: source image off, or VQ
  std::string name_;
  // Fields of fewer than 2^31 samples, on a CPU with AVX-512 F + BW (first choice; every
  // storage mode) or AVX2 + FMA (float and 16-bit).
  bool use_avx512_ = false;
  bool use_avx2_ = false;
  bool avx2_runs_ = true;  // false: every AVX2 sample gathered (SimdLevel::kAvx2Gathers)
};

}  // namespace

LFTRACK_HOT_CLONES
int render_source_image(const SourceImage& image, const LightFieldGeometry& g, const RayMap& m,
                        ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin, int r_end) {
  return render_rows(SourceImageBilinear{image}, m, g, out, valid, cols, r_begin, r_end);
}

Result<std::unique_ptr<DrrRenderer>> make_light_field_renderer(
    std::vector<std::shared_ptr<const LightField>> fields, ThreadPool* pool, SimdLevel simd, bool mips,
    bool source_image) {
  if (fields.empty()) {
    return failed_precondition(
        "the lightfield renderer needs precomputed light fields (run `lftrack precompute`)");
  }
  for (const auto& f : fields) {
    if (!f) return invalid_argument("null light field");
    if (f->header().storage != fields.front()->header().storage) {
      return invalid_argument("light fields of one renderer must share a storage mode");
    }
  }
  std::vector<FieldLevels> levels;
  for (auto& f : fields) {
    FieldLevels& l = levels.emplace_back();
    l.field = std::move(f);
    // A copy needs a few blocks on each (s, t) axis to be worth its memory; a VQ field (chosen to
    // save memory) gets none: its float copies would outweigh it.
    const bool copies = mips && l.field->header().storage != LightFieldStorage::kVq;
    for (std::size_t k = 0; copies && k < l.averaged.size(); ++k) {
      const int factor = 2 << k;
      const auto& size = l.field->geometry().size;
      if (std::min(size[2], size[3]) < 8 * factor) break;
      auto averaged = LightField::downsampled_st(*l.field, factor, pool);
      if (!averaged.ok()) return averaged.status();
      l.averaged[k] = *averaged;
    }
  }
  return std::unique_ptr<DrrRenderer>(std::make_unique<LightFieldRenderer>(std::move(levels), pool, simd, source_image));
}

}  // namespace lftrack::tracking
