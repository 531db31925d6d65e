#include "lftrack/tracking/frame_preprocessing.hpp"

#include <algorithm>
#include <cmath>

namespace lftrack::tracking {

Status preprocess_frame(const ImageView<const std::uint16_t>& raw, const DetectorCorrection& correction,
                        const PixelWindow& window, ImageView<float> line_integral,
                        ImageView<unsigned char> valid) {
  if (raw.empty() || !window.inside(raw.rows, raw.cols))
    return invalid_argument("preprocess: the window lies outside the frame");
  if (line_integral.rows != window.rows || line_integral.cols != window.cols || valid.rows != window.rows ||
      valid.cols != window.cols)
    return invalid_argument("preprocess: the outputs must have the window's size");
  auto fits = [&](const Image<float>& im) {
    return im.pixels().empty() || (im.rows() == raw.rows && im.cols() == raw.cols);
  };
  if (!fits(correction.dark_counts) || !fits(correction.gain))
    return invalid_argument("preprocess: the dark or gain image's size differs from the frame's");
  if (!(correction.open_field_counts > 0) || !std::isfinite(correction.open_field_counts))
    return invalid_argument("preprocess: the open-field level I0 must be positive");
  const bool has_dark = !correction.dark_counts.pixels().empty();
  const bool has_gain = !correction.gain.pixels().empty();
  for (int r = 0; r < window.rows; ++r) {
    const int fr = window.row0 + r;
    for (int c = 0; c < window.cols; ++c) {
      const int fc = window.col0 + c;
      const std::uint16_t counts = raw.at(fr, fc);
      const double dark = has_dark ? correction.dark_counts.at(fr, fc) : 0.0;
      const double gain = has_gain ? correction.gain.at(fr, fc) : 1.0;
      const double intensity = gain > 0 ? (counts - dark) / gain : 0.0;
      const bool ok = counts < correction.saturation_counts && gain > 0 && intensity > 0 && std::isfinite(intensity);
      valid.at(r, c) = ok ? 1 : 0;
      line_integral.at(r, c) = ok ? static_cast<float>(std::log(correction.open_field_counts / intensity)) : 0.f;
    }
  }
  return {};
}

GaussianBlur::GaussianBlur(int rows, int cols, double sigma_px)
    : rows_(rows), cols_(cols), sigma_px_(std::isfinite(sigma_px) && sigma_px > 0 ? sigma_px : 0.0) {
  const int half = sigma_px_ > 0 ? static_cast<int>(std::ceil(3 * sigma_px_)) : 0;
  kernel_.resize(2 * half + 1);
  for (int i = -half; i <= half; ++i)
    kernel_[i + half] = sigma_px_ > 0 ? std::exp(-0.5 * i * i / (sigma_px_ * sigma_px_)) : 1.0;
  const std::size_t n = static_cast<std::size_t>(std::max(rows, 0)) * std::max(cols, 0);
  value_tmp_.assign(n, 0.0);
  weight_tmp_.assign(n, 0.0);
}

Status GaussianBlur::blur(const ImageView<const float>& in, const ImageView<const unsigned char>& valid,
                          ImageView<float> out) {
  if (in.rows != rows_ || in.cols != cols_ || out.rows != rows_ || out.cols != cols_ ||
      (!valid.empty() && (valid.rows != rows_ || valid.cols != cols_)))
    return invalid_argument("blur: image sizes differ from the blur's");
  const int half = static_cast<int>(kernel_.size() / 2);
  auto usable = [&](int r, int c) {
    return (valid.empty() || valid.at(r, c) != 0) && std::isfinite(in.at(r, c));
  };
  // Along rows: weighted values and weights.
  for (int r = 0; r < rows_; ++r) {
    for (int c = 0; c < cols_; ++c) {
      double v = 0, w = 0;
      for (int k = -half; k <= half; ++k) {
        const int cc = c + k;
        if (cc < 0 || cc >= cols_ || !usable(r, cc)) continue;
        v += kernel_[k + half] * in.at(r, cc);
        w += kernel_[k + half];
      }
      value_tmp_[static_cast<std::size_t>(r) * cols_ + c] = v;
      weight_tmp_[static_cast<std::size_t>(r) * cols_ + c] = w;
    }
  }
  // Down columns, then normalise.
  for (int r = 0; r < rows_; ++r) {
    for (int c = 0; c < cols_; ++c) {
      if (!usable(r, c)) {
        out.at(r, c) = in.at(r, c);
        continue;
      }
      double v = 0, w = 0;
      for (int k = -half; k <= half; ++k) {
        const int rr = r + k;
        if (rr < 0 || rr >= rows_) continue;
        v += kernel_[k + half] * value_tmp_[static_cast<std::size_t>(rr) * cols_ + c];
        w += kernel_[k + half] * weight_tmp_[static_cast<std::size_t>(rr) * cols_ + c];
      }
      out.at(r, c) = static_cast<float>(w > 0 ? v / w : in.at(r, c));
    }
  }
  return {};
}

BoxHighPass::BoxHighPass(int rows, int cols, int radius_px)
    : rows_(std::max(rows, 0)),
      cols_(std::max(cols, 0)),
      radius_(std::clamp(radius_px, 1, std::max({rows_, cols_, 1}))),  // a larger box sees no more
      value_sum_(std::size_t(rows_ + 1) * std::size_t(cols_ + 1), 0.0),
      count_sum_(value_sum_.size(), 0.0),
      low_(std::size_t(rows_) * std::size_t(cols_), 0.f) {}

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
  const std::size_t stride = std::size_t(cols_) + 1;
  auto usable = [&](int r, int c) {
    return std::isfinite(in.at(r, c)) && (valid.empty() || valid.at(r, c) != 0);
  };
  auto box = [&](const std::vector<double>& t, int r0, int c0, int r1, int c1) {  // [r0, r1) x [c0, c1)
    return t[std::size_t(r1) * stride + std::size_t(c1)] - t[std::size_t(r0) * stride + std::size_t(c1)] -
           t[std::size_t(r1) * stride + std::size_t(c0)] + t[std::size_t(r0) * stride + std::size_t(c0)];
  };
  for (int r = 0; r < rows_; ++r)
    for (int c = 0; c < cols_; ++c) low_[std::size_t(r) * std::size_t(cols_) + std::size_t(c)] = in.at(r, c);
  // Each pass replaces low_ at the usable pixels by the mean of the usable pixels in the box.
  for (int pass = 0; pass < kPasses; ++pass) {
    for (int r = 0; r < rows_; ++r) {
      double row_value = 0, row_count = 0;
      for (int c = 0; c < cols_; ++c) {
        if (usable(r, c)) {
          row_value += low_[std::size_t(r) * std::size_t(cols_) + std::size_t(c)];
          row_count += 1;
        }
        const std::size_t i = std::size_t(r + 1) * stride + std::size_t(c + 1);
        value_sum_[i] = value_sum_[i - stride] + row_value;
        count_sum_[i] = count_sum_[i - stride] + row_count;
      }
    }
    for (int r = 0; r < rows_; ++r) {
      const int r0 = std::max(0, r - radius_), r1 = std::min(rows_, r + radius_ + 1);
      for (int c = 0; c < cols_; ++c) {
        if (!usable(r, c)) continue;
        const int c0 = std::max(0, c - radius_), c1 = std::min(cols_, c + radius_ + 1);
        const double n = box(count_sum_, r0, c0, r1, c1);  // >= 1: the pixel itself
        low_[std::size_t(r) * std::size_t(cols_) + std::size_t(c)] =
            static_cast<float>(box(value_sum_, r0, c0, r1, c1) / n);
      }
    }
  }
  for (int r = 0; r < rows_; ++r)
    for (int c = 0; c < cols_; ++c)
      out.at(r, c) =
          usable(r, c) ? static_cast<float>(in.at(r, c) - low_[std::size_t(r) * std::size_t(cols_) + std::size_t(c)])
                       : 0.f;
  return {};
}

}  // namespace lftrack::tracking
