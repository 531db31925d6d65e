#include "lftrack/calib/detector_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace lftrack::calib {

namespace {

// Median and robust SD (1.4826 MAD) of `values` (copied; nth_element reorders).
struct Robust {
  double median = 0, sd = 0;
};
Robust robust(std::vector<float> v) {
  Robust r;
  if (v.empty()) return r;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  r.median = *mid;
  for (float& x : v) x = std::abs(x - static_cast<float>(r.median));
  std::nth_element(v.begin(), mid, v.end());
  r.sd = 1.4826 * *mid;
  return r;
}

bool finite_and(double v, double lo, double hi) {
  return std::isfinite(v) && v >= lo && v <= hi;
}

Status check_frames(const std::vector<tracking::Image<std::uint16_t>>& frames, const char* what, int minimum,
                    int rows, int cols) {
  if (static_cast<int>(frames.size()) < minimum)
    return invalid_argument(std::string("too few ") + what + " frames: " + std::to_string(frames.size()) +
                            " (at least " + std::to_string(minimum) + ")");
  for (std::size_t i = 0; i < frames.size(); ++i)
    if (frames[i].rows() != rows || frames[i].cols() != cols)
      return invalid_argument(std::string(what) + " frame " + std::to_string(i + 1) + " is " +
                              std::to_string(frames[i].cols()) + " x " + std::to_string(frames[i].rows()) +
                              " pixels, the first dark frame " + std::to_string(cols) + " x " + std::to_string(rows));
  return {};
}

}  // namespace

const char* defect_rule_name(int rule) {
  static const char* kNames[kDefectRules] = {"dark", "noise", "gain", "saturated", "line"};
  return rule >= 0 && rule < kDefectRules ? kNames[rule] : "?";
}

Status check_detector_calibration_options(const DetectorCalibrationOptions& o) {
  if (o.min_dark_frames < 2 || o.min_dark_frames > 100000 || o.min_flood_frames < 1 || o.min_flood_frames > 100000)
    return invalid_argument("the minimum frame counts must be 2 (dark) or 1 (flood) to 100000");
  if (o.bits < 8 || o.bits > 16) return invalid_argument("bits must be 8 to 16");
  if (o.saturation_counts < 0 || o.saturation_counts > 65535) return invalid_argument("saturation must be 0 to 65535");
  if (!finite_and(o.dark_sd, 1, 1000) || !finite_and(o.noise_sd, 1, 1000))
    return invalid_argument("the dark and noise thresholds must be 1 to 1000 robust SDs");
  if (!finite_and(o.gain_low, 0, 1) || !finite_and(o.gain_high, 1, 100) || !finite_and(o.line_low, 0, 1) ||
      !finite_and(o.line_high, 1, 100))
    return invalid_argument("gain limits must be finite, low in [0, 1], high in [1, 100]");
  if (!finite_and(o.max_saturated_fraction, 0, 1)) return invalid_argument("max_saturated_fraction must be in [0, 1]");
  if (!finite_and(o.min_signal_counts, 0, 65535)) return invalid_argument("min_signal_counts must be in [0, 65535]");
  return {};
}

Result<DetectorCalibration> calibrate_detector(const std::vector<tracking::Image<std::uint16_t>>& dark,
                                               const std::vector<tracking::Image<std::uint16_t>>& flood,
                                               const DetectorCalibrationOptions& o) {
  LFTRACK_RETURN_IF_ERROR(check_detector_calibration_options(o));
  if (dark.empty()) return invalid_argument("no dark frames");
  const int rows = dark[0].rows(), cols = dark[0].cols();
  if (rows <= 0 || cols <= 0) return invalid_argument("the dark frames are empty");
  LFTRACK_RETURN_IF_ERROR(check_frames(dark, "dark", o.min_dark_frames, rows, cols));
  LFTRACK_RETURN_IF_ERROR(check_frames(flood, "flood", o.min_flood_frames, rows, cols));
  const std::size_t n = static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols);
  DetectorCalibration c;
  c.rows = rows;
  c.cols = cols;
  c.dark_frames = static_cast<int>(dark.size());
  c.flood_frames = static_cast<int>(flood.size());
  c.rule = o;
  c.saturation_counts = o.saturation_counts > 0 ? o.saturation_counts : (1 << o.bits) - 1;
  c.offset_counts = tracking::Image<float>(rows, cols, 0.f);
  c.noise_counts = tracking::Image<float>(rows, cols, 0.f);
  c.gain = tracking::Image<float>(rows, cols, 0.f);
  c.defective = tracking::Image<unsigned char>(rows, cols, 0);
  std::vector<unsigned char> saturated(n, 0);
  std::vector<float> offset(n), noise(n), signal(n);
  // Two passes over the dark frames (mean, then spread) in double per pixel.
  std::vector<double> sum(n, 0.0), sum_sq(n, 0.0), flood_sum(n, 0.0);
  for (const auto& f : dark) {
    const std::uint16_t* p = &f.at(0, 0);
    for (std::size_t i = 0; i < n; ++i) sum[i] += p[i];
  }
  const double nd = static_cast<double>(dark.size());
  for (std::size_t i = 0; i < n; ++i) offset[i] = static_cast<float>(sum[i] / nd);
  for (const auto& f : dark) {
    const std::uint16_t* p = &f.at(0, 0);
    for (std::size_t i = 0; i < n; ++i) {
      const double d = p[i] - static_cast<double>(offset[i]);
      sum_sq[i] += d * d;
    }
  }
  for (std::size_t i = 0; i < n; ++i) noise[i] = static_cast<float>(std::sqrt(sum_sq[i] / (nd - 1)));
  std::int64_t saturated_values = 0;
  for (const auto& f : flood) {
    const std::uint16_t* p = &f.at(0, 0);
    for (std::size_t i = 0; i < n; ++i) {
      flood_sum[i] += p[i];
      if (p[i] >= c.saturation_counts) {
        saturated[i] = 1;
        ++saturated_values;
      }
    }
  }
  const double saturated_fraction = static_cast<double>(saturated_values) / (static_cast<double>(n) * static_cast<double>(flood.size()));
  if (saturated_fraction > o.max_saturated_fraction) {
    char why[200];
    std::snprintf(why, sizeof why,
                  "the flood saturates: %.2f %% of its pixel values reach %d counts (at most %.2f %%); lower the "
                  "tube current or the exposure",
                  100 * saturated_fraction, c.saturation_counts, 100 * o.max_saturated_fraction);
    return invalid_argument(why);
  }
  const double nf = static_cast<double>(flood.size());
  for (std::size_t i = 0; i < n; ++i) signal[i] = static_cast<float>(flood_sum[i] / nf - offset[i]);
  const Robust all_signal = robust(signal);
  if (!(all_signal.median > o.min_signal_counts)) {
    char why[200];
    std::snprintf(why, sizeof why,
                  "the flood is no brighter than the dark: median flood - dark is %.1f counts (needs more than %.0f); "
                  "were the dark and flood folders swapped, or the beam off?",
                  all_signal.median, o.min_signal_counts);
    return invalid_argument(why);
  }
  const Robust dark_level = robust(offset), noise_level = robust(noise);
  // A robust SD of 0 (a perfectly flat map) would flag every pixel off by one count: at least 1.
  const double dark_limit = o.dark_sd * std::max(dark_level.sd, 1.0);
  const double noise_limit = o.noise_sd * std::max(noise_level.sd, 0.5);
  std::vector<unsigned char> bad(n, 0);
  const auto mark = [&](std::size_t i, int rule) {
    ++c.defects_by_rule[std::size_t(rule)];
    bad[i] = 1;
  };
  for (std::size_t i = 0; i < n; ++i) {
    if (std::abs(offset[i] - dark_level.median) > dark_limit) mark(i, kDefectDark);
    if (noise[i] - noise_level.median > noise_limit) mark(i, kDefectNoise);
    const double g = signal[i] / all_signal.median;
    if (!(g >= o.gain_low && g <= o.gain_high)) mark(i, kDefectGain);
    if (saturated[i]) mark(i, kDefectSaturated);
  }
  // The open field over the good pixels, then the gain against it.
  std::vector<float> good;
  good.reserve(n);
  for (std::size_t i = 0; i < n; ++i)
    if (!bad[i]) good.push_back(signal[i]);
  if (good.size() < n / 2)
    return invalid_argument("more than half the pixels are defective (" + std::to_string(n - good.size()) + " of " +
                            std::to_string(n) + "): not a detector this rule can calibrate");
  c.open_field_counts = robust(good).median;
  for (std::size_t i = 0; i < n; ++i) c.gain.view().data[i] = static_cast<float>(signal[i] / c.open_field_counts);
  // Whole lines: a row or column whose median gain is off.
  std::vector<float> line;
  for (int r = 0; r < rows; ++r) {
    line.assign(&c.gain.at(r, 0), &c.gain.at(r, 0) + cols);
    const double m = robust(line).median;
    if (m < o.line_low || m > o.line_high)
      for (int k = 0; k < cols; ++k) mark(std::size_t(r) * cols + k, kDefectLine);
  }
  for (int k = 0; k < cols; ++k) {
    line.clear();
    for (int r = 0; r < rows; ++r) line.push_back(c.gain.at(r, k));
    const double m = robust(line).median;
    if (m < o.line_low || m > o.line_high)
      for (int r = 0; r < rows; ++r) mark(std::size_t(r) * cols + k, kDefectLine);
  }
  for (std::size_t i = 0; i < n; ++i) {
    c.offset_counts.view().data[i] = offset[i];
    c.noise_counts.view().data[i] = noise[i];
    c.defective.view().data[i] = bad[i];
    c.defects += bad[i];
  }
  c.content_hash = detector_calibration_hash(c);
  return c;
}

std::string detector_calibration_hash(const DetectorCalibration& c) {
  std::uint64_t h = 1469598103934665603ull;
  const auto mix = [&](const void* data, std::size_t bytes) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < bytes; ++i) {
      h ^= p[i];
      h *= 1099511628211ull;
    }
  };
  const std::size_t n = static_cast<std::size_t>(c.rows) * static_cast<std::size_t>(c.cols);
  mix(&c.rows, sizeof c.rows);
  mix(&c.cols, sizeof c.cols);
  if (c.offset_counts.rows() * c.offset_counts.cols() == static_cast<int>(n) && n > 0) {
    mix(&c.offset_counts.at(0, 0), n * sizeof(float));
    mix(&c.noise_counts.at(0, 0), n * sizeof(float));
    mix(&c.gain.at(0, 0), n * sizeof(float));
    mix(&c.defective.at(0, 0), n);
  }
  mix(&c.open_field_counts, sizeof c.open_field_counts);
  mix(&c.saturation_counts, sizeof c.saturation_counts);
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(h));
  return hex;
}

tracking::DetectorCorrection to_detector_correction(const DetectorCalibration& c) {
  tracking::DetectorCorrection d;
  d.dark_counts = c.offset_counts;
  d.gain = c.gain;
  for (int r = 0; r < c.rows; ++r)
    for (int k = 0; k < c.cols; ++k)
      if (c.defective.at(r, k)) d.gain.at(r, k) = 0.f;
  d.open_field_counts = c.open_field_counts;
  d.saturation_counts = c.saturation_counts;
  return d;
}

}  // namespace lftrack::calib
