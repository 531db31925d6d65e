#include "display_images.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

namespace lftrack::watch {
namespace {

// Block means (NaN where a block has nothing valid) windowed to 0..255 by their percentiles.
GreyImage to_grey(const std::vector<float>& means, int rows, int cols) {
  std::vector<float> finite;
  finite.reserve(means.size());
  for (float v : means)
    if (std::isfinite(v)) finite.push_back(v);
  GreyImage out;
  out.rows = rows;
  out.cols = cols;
  out.pixels.assign(means.size(), 0);
  if (finite.empty()) return out;
  auto percentile = [&](double q) {
    const auto k = static_cast<std::ptrdiff_t>(q * double(finite.size() - 1));
    std::nth_element(finite.begin(), finite.begin() + k, finite.end());
    return finite[std::size_t(k)];
  };
  const float lo = percentile(0.01), hi = percentile(0.99);
  const float scale = hi > lo ? 255.0f / (hi - lo) : 0.0f;
  for (std::size_t i = 0; i < means.size(); ++i)
    if (std::isfinite(means[i]))
      out.pixels[i] = static_cast<std::uint8_t>(std::clamp((means[i] - lo) * scale, 0.0f, 255.0f));
  return out;
}

}  // namespace

int bin_for(int rows, int cols, int max_side) {
  const int longer = std::max(rows, cols);
  return std::max(1, (longer + max_side - 1) / std::max(1, max_side));
}

GreyImage windowed_grey(tracking::ImageView<const float> values, tracking::ImageView<const unsigned char> valid,
                        int bin) {
  bin = std::max(1, bin);
  const int rows = values.rows / bin, cols = values.cols / bin;
  std::vector<float> means(std::size_t(std::max(0, rows)) * std::size_t(std::max(0, cols)), NAN);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      double sum = 0;
      int n = 0;
      for (int dr = 0; dr < bin; ++dr)
        for (int dc = 0; dc < bin; ++dc) {
          const int y = r * bin + dr, x = c * bin + dc;
          const float v = values.at(y, x);
          if (std::isfinite(v) && (valid.empty() || valid.at(y, x) != 0)) {
            sum += v;
            ++n;
          }
        }
      if (n > 0) means[std::size_t(r) * std::size_t(cols) + std::size_t(c)] = static_cast<float>(sum / n);
    }
  return to_grey(means, rows, cols);
}

GreyImage raw_thumbnail(const tracking::Image<std::uint16_t>& raw, int max_side, int* bin) {
  *bin = bin_for(raw.rows(), raw.cols(), max_side);
  const int rows = raw.rows() / *bin, cols = raw.cols() / *bin;
  std::vector<float> means(std::size_t(std::max(0, rows)) * std::size_t(std::max(0, cols)), NAN);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      double sum = 0;
      int n = 0;
      for (int dr = 0; dr < *bin; ++dr)
        for (int dc = 0; dc < *bin; ++dc) {
          const std::uint16_t count = raw.at(r * *bin + dr, c * *bin + dc);
          sum += count;
          n += count > 0;  // 0: not exposed (outside what the detector read out) or dead
        }
      if (n > 0) means[std::size_t(r) * std::size_t(cols) + std::size_t(c)] = static_cast<float>(-std::log(sum / n));
    }
  return to_grey(means, rows, cols);
}

}  // namespace lftrack::watch
