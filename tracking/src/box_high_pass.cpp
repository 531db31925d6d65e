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

// Sums of `in` over [c - radius, c + radius] (clipped to the row), for each c of a row of `cols`.
template <class In, class Sum>
void row_box_sums(const In* in, int cols, int radius, Sum* out) {
  Sum sum = 0;
  for (int c = 0; c <= std::min(radius, cols - 1); ++c) sum += Sum(in[c]);
  out[0] = sum;
  for (int c = 1; c < cols; ++c) {
    if (c + radius < cols) sum += Sum(in[c + radius]);
    if (c - radius - 1 >= 0) sum -= Sum(in[c - radius - 1]);
    out[c] = sum;
  }
}

// row_box_sums for four rows at once: four independent chains of adds, which the core overlaps
// (one row's chain, two dependent adds a pixel, was the filter's bottleneck).
template <class In, class Sum>
void row_box_sums4(const In* in, std::size_t stride, int cols, int radius, Sum* out) {
  Sum s0 = 0, s1 = 0, s2 = 0, s3 = 0;
  const In *i0 = in, *i1 = in + stride, *i2 = in + 2 * stride, *i3 = in + 3 * stride;
  Sum *o0 = out, *o1 = out + stride, *o2 = out + 2 * stride, *o3 = out + 3 * stride;
  for (int c = 0; c <= std::min(radius, cols - 1); ++c) {
    s0 += Sum(i0[c]), s1 += Sum(i1[c]), s2 += Sum(i2[c]), s3 += Sum(i3[c]);
  }
  o0[0] = s0, o1[0] = s1, o2[0] = s2, o3[0] = s3;
  for (int c = 1; c < cols; ++c) {
    if (c + radius < cols) {
      const int k = c + radius;
      s0 += Sum(i0[k]), s1 += Sum(i1[k]), s2 += Sum(i2[k]), s3 += Sum(i3[k]);
    }
    if (c - radius - 1 >= 0) {
      const int k = c - radius - 1;
      s0 -= Sum(i0[k]), s1 -= Sum(i1[k]), s2 -= Sum(i2[k]), s3 -= Sum(i3[k]);
    }
    o0[c] = s0, o1[c] = s1, o2[c] = s2, o3[c] = s3;
  }
}

// row_box_sums for every row of a rows x cols image (rows `stride` apart).
template <class In, class Sum>
void image_row_box_sums(const In* in, int rows, int cols, int radius, Sum* out) {
  const std::size_t stride = std::size_t(cols);
  int r = 0;
  for (; r + 4 <= rows; r += 4)
    row_box_sums4(in + std::size_t(r) * stride, stride, cols, radius, out + std::size_t(r) * stride);
  for (; r < rows; ++r) row_box_sums(in + std::size_t(r) * stride, cols, radius, out + std::size_t(r) * stride);
}

// column_sums += add_row - sub_row (either may be null), across a row.
LFTRACK_HOT_CLONES
void slide_columns(double* column_sums, const double* add_row, const double* sub_row, int cols) {
  if (add_row)
    for (int c = 0; c < cols; ++c) column_sums[c] += add_row[c];
  if (sub_row)
    for (int c = 0; c < cols; ++c) column_sums[c] -= sub_row[c];
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
      row_counts_(usable_.size(), 0),
      column_counts_(std::size_t(cols_), 0),
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
    // The usable pixels in each box (exact, in integers), as the scale of the box's sums.
    image_row_box_sums(usable_.data(), rows_, cols_, radius_, row_counts_.data());
    std::fill(column_counts_.begin(), column_counts_.end(), 0);
    for (int r = 0; r <= std::min(radius_, rows_ - 1); ++r)
      for (std::size_t c = 0; c < cols; ++c) column_counts_[c] += row_counts_[std::size_t(r) * cols + c];
    for (int r = 0; r < rows_; ++r) {
      if (r > 0 && r + radius_ < rows_)
        for (std::size_t c = 0; c < cols; ++c) column_counts_[c] += row_counts_[std::size_t(r + radius_) * cols + c];
      if (r > 0 && r - radius_ - 1 >= 0)
        for (std::size_t c = 0; c < cols; ++c) column_counts_[c] -= row_counts_[std::size_t(r - radius_ - 1) * cols + c];
      for (std::size_t c = 0; c < cols; ++c) {
        const std::size_t i = std::size_t(r) * cols + c;
        inverse_count_[i] = usable_[i] ? 1.0 / double(column_counts_[c]) : 0.0;  // count >= 1: the pixel itself
      }
    }
    counts_ready_ = true;
  }
  // Each pass replaces low_ by the mean of the usable pixels in the box (0 at unusable ones).
  for (int pass = 0; pass < kPasses; ++pass) {
    image_row_box_sums(low_.data(), rows_, cols_, radius_, row_sums_.data());  // floats summed in double
    std::fill(column_sums_.begin(), column_sums_.end(), 0.0);
    for (int r = 0; r <= std::min(radius_, rows_ - 1); ++r)
      slide_columns(column_sums_.data(), row_sums_.data() + std::size_t(r) * cols, nullptr, cols_);
    for (int r = 0; r < rows_; ++r) {
      if (r > 0)
        slide_columns(column_sums_.data(),
                      r + radius_ < rows_ ? row_sums_.data() + std::size_t(r + radius_) * cols : nullptr,
                      r - radius_ - 1 >= 0 ? row_sums_.data() + std::size_t(r - radius_ - 1) * cols : nullptr,
                      cols_);
      scale_row(column_sums_.data(), inverse_count_.data() + std::size_t(r) * cols, cols_,
                low_.data() + std::size_t(r) * cols);
    }
  }
  for (int r = 0; r < rows_; ++r)
    for (int c = 0; c < cols_; ++c) {
      const std::size_t i = std::size_t(r) * cols + std::size_t(c);
      out.at(r, c) = usable_[i] ? in.at(r, c) - low_[i] : 0.f;
    }
  return {};
}

}  // namespace lftrack::tracking
