#include "lftrack/tracking/frame_quality.hpp"

#include <algorithm>
#include <cmath>

namespace lftrack::tracking {

const char* to_string(FrameQualityIssue issue) {
  switch (issue) {
    case FrameQualityIssue::kOk:
      return "ok";
    case FrameQualityIssue::kSaturated:
      return "saturated";
    case FrameQualityIssue::kDeadPixels:
      return "dead pixels";
    case FrameQualityIssue::kBlank:
      return "blank";
    case FrameQualityIssue::kUniform:
      return "uniform";
  }
  return "?";
}

FrameQualityIssue assess_frame_quality(const ImageView<const std::uint16_t>& raw, const PixelWindow& window,
                                       const DetectorCorrection& detector, const FrameQualityLimits& limits,
                                       FrameQualityStats* stats) {
  const int r0 = std::max(0, window.row0), c0 = std::max(0, window.col0);
  const int r1 = std::min(raw.rows, window.row0 + window.rows), c1 = std::min(raw.cols, window.col0 + window.cols);
  FrameQualityStats s;
  if (r1 <= r0 || c1 <= c0) {
    if (stats != nullptr) *stats = s;
    return FrameQualityIssue::kBlank;
  }
  std::int64_t saturated = 0, dead = 0;
  double sum = 0, sum_sq = 0;
  const auto saturation = static_cast<std::uint32_t>(std::max(1, detector.saturation_counts));
  const bool dark = !detector.dark_counts.pixels().empty() && detector.dark_counts.rows() == raw.rows &&
                    detector.dark_counts.cols() == raw.cols;
  for (int r = r0; r < r1; ++r) {
    const std::uint16_t* row = raw.row_ptr(r);
    double row_sum = 0, row_sq = 0;  // per row, so long sums keep their precision
    for (int c = c0; c < c1; ++c) {
      const std::uint32_t v = row[c];
      saturated += v >= saturation;
      dead += v == 0;
      const double signal = double(v) - (dark ? double(detector.dark_counts.at(r, c)) : 0.0);
      row_sum += signal;
      row_sq += signal * signal;
    }
    sum += row_sum;
    sum_sq += row_sq;
  }
  const double n = double(r1 - r0) * double(c1 - c0);
  s.saturated_fraction = double(saturated) / n;
  s.dead_fraction = double(dead) / n;
  s.mean_counts = sum / n;
  const double variance = std::max(0.0, sum_sq / n - s.mean_counts * s.mean_counts);
  s.relative_spread = s.mean_counts > 0 ? std::sqrt(variance) / s.mean_counts : 0;
  if (stats != nullptr) *stats = s;
  if (s.saturated_fraction > limits.max_saturated_fraction) return FrameQualityIssue::kSaturated;
  if (!(s.mean_counts >= limits.min_mean_of_full_scale * double(saturation))) return FrameQualityIssue::kBlank;
  if (s.dead_fraction > limits.max_dead_fraction) return FrameQualityIssue::kDeadPixels;
  if (s.relative_spread < limits.min_relative_spread) return FrameQualityIssue::kUniform;
  return FrameQualityIssue::kOk;
}

}  // namespace lftrack::tracking
