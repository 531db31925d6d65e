// Light-field samples integrated by depth slices: the contract and the geometry are in
// light_field_slices.hpp.

#include "light_field_slices.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include "build_progress.hpp"
#include "cpu_dispatch.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::tracking {
namespace detail {
namespace {

using Eigen::Vector3d;

constexpr double kMinDepthFraction = 0.1;  // of the way from the (u, v) plane to the (s, t) plane
constexpr int kMaxSlices = 65536;
constexpr std::int64_t kMaxSliceSamples = std::int64_t{1} << 22;  // 16 slices of them: 256 MiB
constexpr int kSlicesAChunk = 16;  // resampled together, then added to every ray
constexpr int kDepthSamples = 4;  // box-model samples averaged into each resampled sample
constexpr int kRowsATask = 8;     // rows of s a task adds: all v of them stay in a core's L2 (256 KB)
constexpr int kSlicesAPass = 4;   // slices added together in one pass over a task's rays

// A source sample's shift at one depth, within its slice's rows (or columns): whole samples and the fraction towards the next.
struct Shift {
  int whole = 0;
  float fraction = 0;
};

Shift split(double shift, int lo, int max_whole) {
  const double local = shift - lo;
  const int whole = std::clamp(static_cast<int>(std::floor(local)), 0, max_whole);
  return {whole, static_cast<float>(std::clamp(local - whole, 0.0, 1.0))};
}

// One depth: where it lies, which part of the (s, t)-spaced grid its rays read, and where each
// source sample reads it.
struct Slice {
  double lambda = 0;     // depth / D
  int row_lo = 0;        // first resampled row, in s samples (may be negative)
  int col_lo = 0;        // first resampled column, in t samples
  int rows = 0, cols = 0;
  std::vector<Shift> row_shifts;  // per u sample
  std::vector<Shift> col_shifts;  // per v sample
};

struct Layout {
  double step_mm = 0;  // depth between slices
  std::vector<Slice> slices;
  int max_rows = 0, max_cols = 0;
};

// The shift, in (s, t) samples, of source sample `index` of an axis at depth fraction lambda.
double shift_samples(const LightFieldGeometry& g, int axis, int index, double lambda) {
  const double source_mm = g.lo[axis] + index * g.spacing(axis);
  return (1 - lambda) / lambda * source_mm / g.spacing(axis + 2);
}

Result<Layout> lay_out(const MuVolume& mu, const LightFieldGeometry& g, double step_mm) {
  const double distance_mm = (g.roi_centre_ct_mm - g.source_ct_mm).norm();
  // The depth range of the voxels' box along the axis.
  const VolumeGeometry& vg = mu.geometry;
  const Eigen::Affine3d ct_from_index = vg.ct_from_index();
  double z_lo = HUGE_VAL, z_hi = -HUGE_VAL;
  for (int corner = 0; corner < 8; ++corner) {
    Vector3d index;
    for (int a = 0; a < 3; ++a) index[a] = (corner >> a & 1) ? vg.size[a] - 0.5 : -0.5;
    const double z = (ct_from_index * index - g.source_ct_mm).dot(g.axis);
    z_lo = std::min(z_lo, z);
    z_hi = std::max(z_hi, z);
  }
  if (!(z_lo >= kMinDepthFraction * distance_mm))
    return failed_precondition("the volume reaches within a tenth of the way from the source to the ROI");
  Layout layout;
  const int count = static_cast<int>(std::min(std::ceil((z_hi - z_lo) / step_mm), double(kMaxSlices + 1)));
  if (count > kMaxSlices) return failed_precondition("more than 65536 slices");
  layout.step_mm = (z_hi - z_lo) / std::max(count, 1);
  for (int k = 0; k < count; ++k) {
    Slice s;
    s.lambda = (z_lo + (k + 0.5) * layout.step_mm) / distance_mm;
    std::vector<double> shifts[2];
    for (int axis = 0; axis < 2; ++axis)
      for (int i = 0; i < g.size[axis]; ++i) shifts[axis].push_back(shift_samples(g, axis, i, s.lambda));
    const auto [u_lo, u_hi] = std::minmax_element(shifts[0].begin(), shifts[0].end());
    const auto [v_lo, v_hi] = std::minmax_element(shifts[1].begin(), shifts[1].end());
    s.row_lo = static_cast<int>(std::floor(*u_lo));
    s.col_lo = static_cast<int>(std::floor(*v_lo));
    // A ray reads the resampled sample at its shifted index and the next one.
    s.rows = g.size[2] + static_cast<int>(std::floor(*u_hi)) - s.row_lo + 1;
    s.cols = g.size[3] + static_cast<int>(std::floor(*v_hi)) - s.col_lo + 1;
    for (double shift : shifts[0]) s.row_shifts.push_back(split(shift, s.row_lo, s.rows - g.size[2] - 1));
    for (double shift : shifts[1]) s.col_shifts.push_back(split(shift, s.col_lo, s.cols - g.size[3] - 1));
    layout.max_rows = std::max(layout.max_rows, s.rows);
    layout.max_cols = std::max(layout.max_cols, s.cols);
    layout.slices.push_back(s);
  }
  if (std::int64_t{layout.max_rows} * layout.max_cols > kMaxSliceSamples)
    return failed_precondition("a resampled slice of more than 2^22 samples");
  return layout;
}

// mu at continuous voxel index (x, y, z) in the voxels' box model (each voxel's value over its
// whole box [i - 0.5, i + 0.5), as the Siddon walk integrates it); 0 outside the box.
float voxel_at(const float* mu, const Eigen::Vector3i& n, const Vector3d& index) {
  const double x = std::floor(index.x() + 0.5), y = std::floor(index.y() + 0.5), z = std::floor(index.z() + 0.5);
  if (!(x >= 0 && x < n.x() && y >= 0 && y < n.y() && z >= 0 && z < n.z())) return 0;
  return mu[static_cast<std::ptrdiff_t>(x) +
            std::ptrdiff_t{n.x()} * (static_cast<std::ptrdiff_t>(y) + std::ptrdiff_t{n.y()} * static_cast<std::ptrdiff_t>(z))];
}

// Interpolates `rows` rows of a resampled slice (`cols` wide) at `first_row` + `fraction`
// towards the next row, into `out` (rows x cols).
LFTRACK_HOT_CLONES
void interpolate_rows(const float* slice, int cols, int first_row, float fraction, int rows, float* out) {
  for (int r = 0; r < rows; ++r) {
    const float* __restrict a = slice + std::ptrdiff_t{first_row + r} * cols;
    const float* __restrict b = a + cols;
    float* __restrict d = out + std::ptrdiff_t{r} * cols;
    for (int c = 0; c < cols; ++c) d[c] = a[c] + fraction * (b[c] - a[c]);
  }
}

// One slice's share of a pass: its rows for the task, interpolated in s (rows x cols), and each
// v sample's shift in t.
struct SliceRows {
  const float* rows = nullptr;
  int cols = 0;
  const Shift* col_shifts = nullptr;
};

// Adds kSlicesAPass slices to the rays of one u sample, `rows` rows of s, every v; `out` is the
// field at (u, v = 0, first s, t = 0). Four slices a pass over the field's rows: one slice a pass
// spent most of its time loading and storing them (it was bound by the L2 cache).
LFTRACK_HOT_CLONES
void add_slices(const SliceRows* slices, int rows, int v_count, std::ptrdiff_t v_stride, int t_count, float* out) {
  static_assert(kSlicesAPass == 4);
  for (int r = 0; r < rows; ++r) {
    for (int v = 0; v < v_count; ++v) {
      const float* __restrict a[kSlicesAPass];
      float f[kSlicesAPass];
      for (int k = 0; k < kSlicesAPass; ++k) {
        a[k] = slices[k].rows + std::ptrdiff_t{r} * slices[k].cols + slices[k].col_shifts[v].whole;
        f[k] = slices[k].col_shifts[v].fraction;
      }
      const float* __restrict a0 = a[0];
      const float* __restrict a1 = a[1];
      const float* __restrict a2 = a[2];
      const float* __restrict a3 = a[3];
      float* __restrict o = out + v * v_stride + std::ptrdiff_t{r} * t_count;
      for (int t = 0; t < t_count; ++t) {
        o[t] += ((a0[t] + f[0] * (a0[t + 1] - a0[t])) + (a1[t] + f[1] * (a1[t + 1] - a1[t]))) +
                ((a2[t] + f[2] * (a2[t + 1] - a2[t])) + (a3[t] + f[3] * (a3[t + 1] - a3[t])));
      }
    }
  }
}

}  // namespace

Status integrate_by_slices(const MuVolume& mu, const LightFieldGeometry& g, double step_mm, float* samples,
                           ThreadPool* pool, const std::function<void(double)>& progress) {
  auto laid = lay_out(mu, g, light_field_slice_step_mm(mu, step_mm));
  if (!laid.ok()) return laid.status();
  const Layout& layout = *laid;
  const int nu = g.size[0], nv = g.size[1], ns = g.size[2], nt = g.size[3];
  const std::ptrdiff_t v_stride = std::ptrdiff_t{ns} * nt;
  const double distance_mm = (g.roi_centre_ct_mm - g.source_ct_mm).norm();
  const int slice_count = static_cast<int>(layout.slices.size());
  const int s_blocks = (ns + kRowsATask - 1) / kRowsATask;
  const int tasks = nu * s_blocks;
  const int chunks = (slice_count + kSlicesAChunk - 1) / kSlicesAChunk;
  BuildProgress report(progress, std::int64_t{chunks} * tasks);
  std::fill(samples, samples + g.sample_count(), 0.0f);
  const std::ptrdiff_t slice_size = std::ptrdiff_t{layout.max_rows} * layout.max_cols;
  std::vector<float> resampled(static_cast<std::size_t>(slice_size) * kSlicesAChunk);
  const Eigen::Affine3d index_from_ct = mu.geometry.index_from_ct();
  const Eigen::Vector3i n = mu.geometry.size;
  auto run = [&](int count, int grain, const auto& body) {
    if (pool)
      pool->parallel_for(count, grain, body);
    else
      body(0, count);
  };
  for (int chunk = 0; chunk < chunks; ++chunk) {
    const int k0 = chunk * kSlicesAChunk, k_count = std::min(kSlicesAChunk, slice_count - k0);
    // The volume on each slice's grid: row i, column j at S + z n + lambda ((s_lo + i ds) e1 +
    // (t_lo + j dt) e2), in the slice's own rows and columns.
    run(k_count * layout.max_rows, 4, [&](int begin, int end) {
      for (int job = begin; job < end; ++job) {
        const int kk = job / layout.max_rows, row = job % layout.max_rows;
        const Slice& s = layout.slices[static_cast<std::size_t>(k0 + kk)];
        if (row >= s.rows) continue;
        const Vector3d at_row = g.source_ct_mm + s.lambda * distance_mm * g.axis +
                                s.lambda * (g.lo[2] + (s.row_lo + row) * g.spacing(2)) * g.e1 +
                                s.lambda * (g.lo[3] + s.col_lo * g.spacing(3)) * g.e2;
        const Vector3d start = index_from_ct * at_row;
        const Vector3d step = index_from_ct.linear() * (s.lambda * g.spacing(3) * g.e2);
        float* out = resampled.data() + kk * slice_size + std::ptrdiff_t{row} * s.cols;
        // The slice's mean along the axis, from kDepthSamples box-model samples spread over its
        // depth step (a ray crosses a slice within a few degrees of the axis).
        const Vector3d depth_step = index_from_ct.linear() * (layout.step_mm / kDepthSamples * g.axis);
        const Vector3d first = start - (0.5 * (kDepthSamples - 1)) * depth_step;
        for (int col = 0; col < s.cols; ++col) {
          float sum = 0;
          for (int q = 0; q < kDepthSamples; ++q) sum += voxel_at(mu.values.data(), n, first + col * step + q * depth_step);
          out[col] = sum * (1.0f / kDepthSamples);
        }
      }
    });
    // Each task: one u sample, kRowsATask rows of s, every v, the chunk's slices in order (the
    // same order whatever the threads).
    run(tasks, 1, [&](int begin, int end) {
      const std::size_t part = static_cast<std::size_t>(kRowsATask) * static_cast<std::size_t>(layout.max_cols);
      std::vector<float> scratch(part * kSlicesAPass);
      // A chunk's last pass may hold fewer slices: the rest read zeros.
      const std::vector<float> zeros(static_cast<std::size_t>(kRowsATask) * static_cast<std::size_t>(nt + 1), 0.0f);
      const std::vector<Shift> no_shifts(static_cast<std::size_t>(nv));
      for (int task = begin; task < end; ++task) {
        const int iu = task / s_blocks, first_s = (task % s_blocks) * kRowsATask;
        const int rows = std::min(kRowsATask, ns - first_s);
        float* out = samples + std::ptrdiff_t{iu} * nv * v_stride + std::ptrdiff_t{first_s} * nt;
        for (int kk = 0; kk < k_count; kk += kSlicesAPass) {
          SliceRows parts[kSlicesAPass];
          for (int p = 0; p < kSlicesAPass; ++p) {
            if (kk + p >= k_count) {
              parts[p] = {zeros.data(), nt + 1, no_shifts.data()};
              continue;
            }
            const Slice& s = layout.slices[static_cast<std::size_t>(k0 + kk + p)];
            const Shift row = s.row_shifts[static_cast<std::size_t>(iu)];
            float* rows_of_p = scratch.data() + static_cast<std::size_t>(p) * part;
            interpolate_rows(resampled.data() + (kk + p) * slice_size, s.cols, first_s + row.whole, row.fraction, rows,
                             rows_of_p);
            parts[p] = {rows_of_p, s.cols, s.col_shifts.data()};
          }
          add_slices(parts, rows, nv, v_stride, nt, out);
        }
        report.advance();
      }
    });
  }
  // Each slice's length along its ray.
  run(nu * nv, 4, [&](int begin, int end) {
    for (int uv = begin; uv < end; ++uv) {
      const double u = g.lo[0] + (uv / nv) * g.spacing(0), v = g.lo[1] + (uv % nv) * g.spacing(1);
      float* out = samples + std::ptrdiff_t{uv} * v_stride;
      for (int is = 0; is < ns; ++is) {
        const double ds = g.lo[2] + is * g.spacing(2) - u;
        for (int it = 0; it < nt; ++it) {
          const double dt = g.lo[3] + it * g.spacing(3) - v;
          const double length = layout.step_mm * std::sqrt(1 + (ds * ds + dt * dt) / (distance_mm * distance_mm));
          out[is * nt + it] = static_cast<float>(out[is * nt + it] * length);
        }
      }
    }
  });
  return {};
}

}  // namespace detail

double light_field_slice_step_mm(const MuVolume& mu, double step_mm) {
  return step_mm > 0 && std::isfinite(step_mm) ? step_mm : mu.geometry.spacing_mm.minCoeff();
}

}  // namespace lftrack::tracking
