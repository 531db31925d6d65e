#pragma once
// Private to the volume renderers (ray casters, octree): the loop that renders one ray per
// pixel, from the source to the pixel centre, in the volume's grid frame.

#include <algorithm>

#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::tracking {

// out(r, c) = the line integral from the source to pixel centre (r, c), both points in the grid
// frame of `geometry` (VolumeGeometry::grid_from_ct) for the CT placed by T_room_from_ct; every
// pixel is valid. Rows are spread over `pool` when given. A row at a time:
// row_integrals(source, first_pixel, per_col, cols, dst) writes dst[c] for the row's pixels
// first_pixel + c per_col, c = 0 .. cols - 1.
template <class RowIntegrals>
void render_pixel_ray_rows(const VolumeGeometry& geometry, const Pose& T_room_from_ct, const XrayView& view,
                           const PixelWindow& window, ImageView<float> out, RenderExtras* extras,
                           ThreadPool* pool, const RowIntegrals& row_integrals) {
  // Everything in the grid frame: pixel centres are affine in (row, col).
  const Eigen::Isometry3d T_grid_from_room = geometry.grid_from_ct() * T_room_from_ct.inverse();
  const Eigen::Vector3d source = T_grid_from_room * view.source_mm;
  const Eigen::Vector3d pixel00 = T_grid_from_room * view.pixel00_mm;
  const Eigen::Vector3d per_col = T_grid_from_room.linear() * view.col_axis * view.pitch_col_mm;
  const Eigen::Vector3d per_row = T_grid_from_room.linear() * view.row_axis * view.pitch_row_mm;
  auto rows_body = [&](int r_begin, int r_end) {
    for (int r = r_begin; r < r_end; ++r) {
      if (extras->valid.data)
        std::fill_n(extras->valid.row_ptr(r), window.cols, static_cast<unsigned char>(1));
      const Eigen::Vector3d row_start = pixel00 + per_row * (window.row0 + r) + per_col * window.col0;
      row_integrals(source, row_start, per_col, window.cols, out.row_ptr(r));
    }
  };
  if (pool) {
    pool->parallel_for(window.rows, 4, rows_body);
  } else {
    rows_body(0, window.rows);
  }
}

// The same, a pixel at a time: out(r, c) = line_integral(source, pixel centre).
template <class LineIntegral>
void render_pixel_rays(const VolumeGeometry& geometry, const Pose& T_room_from_ct, const XrayView& view,
                       const PixelWindow& window, ImageView<float> out, RenderExtras* extras,
                       ThreadPool* pool, const LineIntegral& line_integral) {
  render_pixel_ray_rows(
      geometry, T_room_from_ct, view, window, out, extras, pool,
      [&](const Eigen::Vector3d& source, const Eigen::Vector3d& first_pixel, const Eigen::Vector3d& per_col,
          int cols, float* dst) {
        for (int c = 0; c < cols; ++c)
          dst[c] = static_cast<float>(line_integral(source, Eigen::Vector3d(first_pixel + per_col * c)));
      });
}

}  // namespace lftrack::tracking
