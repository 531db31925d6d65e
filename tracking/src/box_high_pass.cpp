// BoxHighPass (frame_preprocessing.hpp): kPasses box means of the usable pixels, each box mean
// separable: a running sum along each row, then a running sum down the columns, divided by the
// number of usable pixels in the box.
//
// Cost per pixel and pass: two adds along the row, two down the column (four pixels a vector
// where the CPU has AVX2) and one multiply; no division, and the counts are not recomputed while
// the usable pixels stay the same (a registration high-passes every DRR over the same pixels).
// The summed-area tables this replaced did eight reads and a division per pixel and pass, and
// were 70 % of the robust registration's time.

#include <algorithm>
#include <cmath>

#include "cpu_dispatch.hpp"
#include "lftrack/tracking/frame_preprocessing.hpp"

namespace lftrack::tracking {
namespace {

// Sums of `in` over [c - radius, c + radius] (clipped to the row), for each c, in kRows rows
// `stride` apart at once: kRows independent chains of adds, which the core overlaps (one row's
// chain, two dependent adds a pixel, was the filter's bottleneck).
template <int kRows, class In, class Sum>
void row_box_sums(const In* in, std::size_t stride, int cols, int radius, Sum* out) {
  Sum sum[kRows] = {};
  for (int c = 0; c <= std::min(radius, cols - 1); ++c)
    for (int k = 0; k < kRows; ++k) sum[k] += Sum(in[std::size_t(k) * stride + std::size_t(c)]);
  for (int k = 0; k < kRows; ++k) out[std::size_t(k) * stride] = sum[k];
  for (int c = 1; c < cols; ++c) {
    if (c + radius < cols)
      for (int k = 0; k < kRows; ++k) sum[k] += Sum(in[std::size_t(k) * stride + std::size_t(c + radius)]);
    if (c - radius - 1 >= 0)
      for (int k = 0; k < kRows; ++k) sum[k] -= Sum(in[std::size_t(k) * stride + std::size_t(c - radius - 1)]);
    for (int k = 0; k < kRows; ++k) out[std::size_t(k) * stride + std::size_t(c)] = sum[k];
  }
}

// row_box_sums for every row of a rows x cols image, four rows at a time.
template <class In>
void image_row_box_sums(const In* in, int rows, int cols, int radius, double* out) {
  const std::size_t stride = std::size_t(cols);
  int r = 0;
  for (; r + 4 <= rows; r += 4)
    row_box_sums<4>(in + std::size_t(r) * stride, stride, cols, radius, out + std::size_t(r) * stride);
  for (; r < rows; ++r) row_box_sums<1>(in + std::size_t(r) * stride, stride, cols, radius, out + std::size_t(r) * stride);
}

// column_sums += add_row - sub_row (either may be null), across a row.
LFTRACK_HOT_CLONES
void slide_columns(double* column_sums, const double* add_row, const double* sub_row, int cols) {
  if (add_row)
    for (int c = 0; c < cols; ++c) column_sums[c] += add_row[c];
  if (sub_row)
    for (int c = 0; c < cols; ++c) column_sums[c] -= sub_row[c];
}

// Slides a box of rows [r - radius, r + radius] down `row_sums` (rows x cols) and calls
// at_row(r, column_sums) with the box's sums for each row r.
template <class AtRow>
void column_box_sums(const double* row_sums, int rows, int cols, int radius, double* column_sums, AtRow at_row) {
  const std::size_t stride = std::size_t(cols);
  std::fill(column_sums, column_sums + cols, 0.0);
  for (int r = 0; r <= std::min(radius, rows - 1); ++r)
    slide_columns(column_sums, row_sums + std::size_t(r) * stride, nullptr, cols);
  for (int r = 0; r < rows; ++r) {
    if (r > 0)
      slide_columns(column_sums, r + radius < rows ? row_sums + std::size_t(r + radius) * stride : nullptr,
                    r - radius - 1 >= 0 ? row_sums + std::size_t(r - radius - 1) * stride : nullptr, cols);
    at_row(r, column_sums);
  }
}

// out = column_sums * scale, across a row (scale is 0 at unusable pixels).
LFTRACK_HOT_CLONES
void scale_row(const double* column_sums, const double* scale, int cols, float* out) {
  for (int c = 0; c < cols; ++c) out[c] = static_cast<float>(column_sums[c] * scale[c]);
}

}  // namespace

BoxHighPass::BoxHighPass(int rows, int cols, int radius_px)
    : rows_(std::max(rows, 0)),
      cols_(std::max(cols, 0)),
      radius_(std::clamp(radius_px, 1, std::max({rows_, cols_, 1}))),  // a larger box sees no more
      usable_(std::size_t(rows_) * std::size_t(cols_), 0),
      inverse_count_(usable_.size(), 0.0),
      row_sums_(usable_.size(), 0.0),
      column_sums_(std::size_t(cols_), 0.0),
      low_(usable_.size(), 0.f) {}

int BoxHighPass::radius_for_sigma(double sigma_px) {
  if (!std::isfinite(sigma_px) || sigma_px <= 0) return 1;
  // kPasses boxes of width 2r+1: sigma^2 = kPasses * ((2r+1)^2 - 1) / 12
  const double s = std::min(sigma_px, 1e4);
  const double width = std::sqrt(12.0 * s * s / kPasses + 1.0);
  return std::max(1, static_cast<int>(std::lround(0.5 * (width - 1.0))));
}

Status BoxHighPass::apply(const ImageView<const float>& in, const ImageView<const unsigned char>& valid,
                          ImageView<float> out) {
  if (in.rows != rows_ || in.cols != cols_ || out.rows != rows_ || out.cols != cols_ ||
      (!valid.empty() && (valid.rows != rows_ || valid.cols != cols_)))
    return invalid_argument("high-pass: image sizes differ from the filter's");
  if (rows_ == 0 || cols_ == 0) return {};
  const std::size_t cols = std::size_t(cols_);
  // The usable pixels (low_ holds 0 elsewhere, so sums may run over every pixel), and whether
  // they differ from the last call's.
  bool same_pixels = counts_ready_;
  for (int r = 0; r < rows_; ++r) {
    for (int c = 0; c < cols_; ++c) {
      const float v = in.at(r, c);
      const unsigned char usable = std::isfinite(v) && (valid.empty() || valid.at(r, c) != 0);
      const std::size_t i = std::size_t(r) * cols + std::size_t(c);
      same_pixels = same_pixels && usable_[i] == usable;
      usable_[i] = usable;
      low_[i] = usable ? v : 0.f;
    }
  }
  if (!same_pixels) {
    // The usable pixels in each box (0/1 summed in double: exact), as the scale of its sums.
    image_row_box_sums(usable_.data(), rows_, cols_, radius_, row_sums_.data());
    column_box_sums(row_sums_.data(), rows_, cols_, radius_, column_sums_.data(), [&](int r, const double* counts) {
      for (std::size_t c = 0; c < cols; ++c) {
        const std::size_t i = std::size_t(r) * cols + c;
        inverse_count_[i] = usable_[i] ? 1.0 / counts[c] : 0.0;  // count >= 1: the pixel itself
      }
    });
    counts_ready_ = true;
  }
  // Each pass replaces low_ by the mean of the usable pixels in the box (0 at unusable ones).
  for (int pass = 0; pass < kPasses; ++pass) {
    image_row_box_sums(low_.data(), rows_, cols_, radius_, row_sums_.data());  // floats summed in double
    column_box_sums(row_sums_.data(), rows_, cols_, radius_, column_sums_.data(), [&](int r, const double* sums) {
      scale_row(sums, inverse_count_.data() + std::size_t(r) * cols, cols_, low_.data() + std::size_t(r) * cols);
    });
  }
  for (int r = 0; r < rows_; ++r)
    for (int c = 0; c < cols_; ++c) {
      const std::size_t i = std::size_t(r) * cols + std::size_t(c);
      out.at(r, c) = usable_[i] ? in.at(r, c) - low_[i] : 0.f;
    }
  return {};
}

}  // namespace lftrack::tracking
