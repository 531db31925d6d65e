#include "lftrack/calib/detector_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>

namespace lftrack::calib {

namespace {

// Median and robust SD (1.4826 MAD) of `values` (copied; nth_element reorders). For an even
// count the upper of the two middle values.
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

double median_of(std::vector<float>* v) {
  if (v->empty()) return 0;
  const auto mid = v->begin() + static_cast<std::ptrdiff_t>(v->size() / 2);
  std::nth_element(v->begin(), mid, v->end());
  return *mid;
}

bool finite_in(double v, double lo, double hi) {
  return std::isfinite(v) && v >= lo && v <= hi;
}

std::string format(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
std::string format(const char* fmt, ...) {
  char buffer[512];
  va_list args;
  va_start(args, fmt);
  std::vsnprintf(buffer, sizeof buffer, fmt, args);
  va_end(args);
  return buffer;
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
                              " pixels, the first dark frame " + std::to_string(cols) + " x " +
                              std::to_string(rows) + ": all frames must be one size");
  return {};
}

// Refuses two identical frames, named by `names` (one per frame) or by their place (1-based).
Status check_not_frozen(const std::vector<tracking::Image<std::uint16_t>>& frames, const char* what,
                        const std::vector<std::string>& names) {
  const auto same = identical_frames(frames);
  if (!same) return {};
  const bool named = names.size() == frames.size();
  const auto name = [&](std::size_t i) { return named ? names[i] : std::to_string(i + 1); };
  return invalid_argument(std::string(what) + " frames " + name(same->first) + " and " + name(same->second) +
                          (named ? "" : " (of " + std::to_string(frames.size()) + ", in the order given)") +
                          " are identical pixel for pixel: a detector's frames differ by their noise, so these are "
                          "a frozen detector's or one file copied; take the frames again");
}

}  // namespace

std::optional<std::pair<std::size_t, std::size_t>> identical_frames(
    const std::vector<tracking::Image<std::uint16_t>>& frames) {
  // FNV-1a of each frame, then a pixel-for-pixel comparison of those with equal hashes.
  std::vector<std::uint64_t> hashes;
  hashes.reserve(frames.size());
  for (const auto& f : frames) {
    std::uint64_t h = 1469598103934665603ull;
    for (std::uint16_t p : f.pixels()) {
      h ^= p;
      h *= 1099511628211ull;
    }
    hashes.push_back(h);
  }
  for (std::size_t j = 1; j < frames.size(); ++j)
    for (std::size_t i = 0; i < j; ++i)
      if (hashes[i] == hashes[j] && frames[i].rows() == frames[j].rows() && frames[i].cols() == frames[j].cols() &&
          frames[i].pixels() == frames[j].pixels())
        return std::make_pair(i, j);
  return std::nullopt;
}

const char* defect_rule_name(int rule) {
  static const char* kNames[kDefectRules] = {"dark", "noise", "gain", "saturated", "line"};
  return rule >= 0 && rule < kDefectRules ? kNames[rule] : "?";
}

std::string describe_defect_rule(const DetectorCalibrationOptions& o) {
  return format(
             "a pixel is defective if its dark level is more than %g robust SDs (1.4826 MAD, at least 1 count) "
             "from the median dark level, or its temporal noise more than %g robust SDs (at least 0.5 counts) "
             "above the median noise, or its flood-minus-dark signal outside [%g, %g] of the median signal, or it "
             "is saturated in any flood frame; ",
             o.dark_sd, o.noise_sd, o.gain_low, o.gain_high) +
         format("a whole row or column is defective if its median signal is outside [%g, %g] of the median or "
                "more than %g of its pixels are defective",
                o.line_low, o.line_high, o.line_defect_fraction);
}

Status check_detector_calibration_options(const DetectorCalibrationOptions& o) {
  if (o.min_dark_frames < 2 || o.min_dark_frames > 100000)
    return invalid_argument("the minimum number of dark frames must be 2 to 100000 (a noise estimate needs 2)");
  if (o.min_flood_frames < 1 || o.min_flood_frames > 100000)
    return invalid_argument("the minimum number of flood frames must be 1 to 100000");
  if (o.bits != 0 && (o.bits < 8 || o.bits > 16)) return invalid_argument("bits must be 8 to 16 (0: inferred)");
  if (o.saturation_counts < 0 || o.saturation_counts > 65535)
    return invalid_argument("the saturation level must be 1 to 65535 counts (0: from the bit depth)");
  if (!finite_in(o.dark_sd, 1, 1000) || !finite_in(o.noise_sd, 1, 1000))
    return invalid_argument("the dark and noise thresholds must be finite, 1 to 1000 robust SDs");
  if (!finite_in(o.gain_low, 0, 1) || o.gain_low >= 1 || !finite_in(o.gain_high, 1, 100) || o.gain_high <= 1)
    return invalid_argument("the gain limits must be finite, low in [0, 1), high in (1, 100]");
  if (!finite_in(o.line_low, 0, 1) || o.line_low >= 1 || !finite_in(o.line_high, 1, 100) || o.line_high <= 1)
    return invalid_argument("the line limits must be finite, low in [0, 1), high in (1, 100]");
  if (!finite_in(o.line_defect_fraction, 0, 1) || o.line_defect_fraction <= 0)
    return invalid_argument("the line defect fraction must be finite, in (0, 1]");
  if (!finite_in(o.max_saturated_fraction, 0, 1))
    return invalid_argument("the saturated fraction allowed must be finite, in [0, 1]");
  if (!finite_in(o.min_signal_counts, 0, 65535))
    return invalid_argument("the minimum flood signal must be finite, 0 to 65535 counts");
  if (!finite_in(o.max_unlit_fraction, 0, 1))
    return invalid_argument("the unlit fraction allowed must be finite, in [0, 1]");
  return {};
}

Result<DetectorCalibration> calibrate_detector(const std::vector<tracking::Image<std::uint16_t>>& dark,
                                               const std::vector<tracking::Image<std::uint16_t>>& flood,
                                               const DetectorCalibrationOptions& o) {
  LFTRACK_RETURN_IF_ERROR(check_detector_calibration_options(o));
  if (dark.empty()) return invalid_argument("no dark frames (at least " + std::to_string(o.min_dark_frames) + ")");
  const int rows = dark[0].rows(), cols = dark[0].cols();
  if (rows <= 0 || cols <= 0) return invalid_argument("the first dark frame is empty (0 pixels)");
  if (rows < kMinDetectorSide || cols < kMinDetectorSide)
    return invalid_argument(format("the frames are %d x %d pixels; a calibration needs at least %d x %d: the defect "
                                   "rule judges each pixel against the median and spread of all pixels and each row "
                                   "and column against the others, which a smaller frame has too few of",
                                   cols, rows, kMinDetectorSide, kMinDetectorSide));
  LFTRACK_RETURN_IF_ERROR(check_frames(dark, "dark", o.min_dark_frames, rows, cols));
  LFTRACK_RETURN_IF_ERROR(check_frames(flood, "flood", o.min_flood_frames, rows, cols));
  LFTRACK_RETURN_IF_ERROR(check_not_frozen(dark, "dark", o.dark_names));
  const std::size_t n = static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols);
  DetectorCalibration c;
  c.rows = rows;
  c.cols = cols;
  c.dark_frames = static_cast<int>(dark.size());
  c.flood_frames = static_cast<int>(flood.size());
  c.rule = o;
  c.rule.dark_names.clear();  // the thresholds, not the frames they judged
  c.rule.flood_names.clear();

  // Dark frames, two passes: the mean (exact integer sums), then the spread about it.
  std::vector<float> offset(n), noise(n), signal(n);
  std::uint16_t largest = 0;
  {
    std::vector<std::uint64_t> sum(n, 0);
    for (const auto& f : dark) {
      const std::uint16_t* p = f.pixels().data();
      for (std::size_t i = 0; i < n; ++i) {
        sum[i] += p[i];
        largest = std::max(largest, p[i]);
      }
    }
    const double nd = static_cast<double>(dark.size());
    std::vector<double> mean(n), sum_sq(n, 0.0);
    for (std::size_t i = 0; i < n; ++i) mean[i] = static_cast<double>(sum[i]) / nd;
    for (const auto& f : dark) {
      const std::uint16_t* p = f.pixels().data();
      for (std::size_t i = 0; i < n; ++i) {
        const double d = p[i] - mean[i];
        sum_sq[i] += d * d;
      }
    }
    for (std::size_t i = 0; i < n; ++i) {
      offset[i] = static_cast<float>(mean[i]);
      noise[i] = static_cast<float>(std::sqrt(sum_sq[i] / (nd - 1)));
    }
    // Flood frames: the mean and each pixel's brightest value.
    std::fill(sum.begin(), sum.end(), 0);
    std::vector<std::uint16_t> brightest(n, 0);
    for (const auto& f : flood) {
      const std::uint16_t* p = f.pixels().data();
      for (std::size_t i = 0; i < n; ++i) {
        sum[i] += p[i];
        brightest[i] = std::max(brightest[i], p[i]);
      }
    }
    for (std::size_t i = 0; i < n; ++i) largest = std::max(largest, brightest[i]);
    // The saturation level: stated, from the bit depth, or the smallest common full scale
    // (8, 10, 12, 14 or 16 bits) that holds every raw value seen.
    if (o.saturation_counts > 0) {
      c.saturation_counts = o.saturation_counts;
      c.saturation_source = "option";
    } else if (o.bits > 0) {
      c.saturation_counts = (1 << o.bits) - 1;
      c.saturation_source = "bits";
    } else {
      int b = 8;
      while (b < 16 && largest > (1 << b) - 1) b += 2;
      c.saturation_counts = (1 << b) - 1;
      c.saturation_source = "observed";
    }
    std::int64_t saturated_values = 0;
    const auto level = static_cast<std::uint16_t>(c.saturation_counts);
    for (const auto& f : flood) {
      const std::uint16_t* p = f.pixels().data();
      for (std::size_t i = 0; i < n; ++i) saturated_values += p[i] >= level;
    }
    const double saturated_fraction =
        static_cast<double>(saturated_values) / (static_cast<double>(n) * static_cast<double>(flood.size()));
    if (saturated_fraction > o.max_saturated_fraction)
      return invalid_argument(
          format("the flood saturates: %.2f %% of its pixel values are at or above %d counts (saturation "
                 "from %s; at "
                 "most %.2f %% allowed); lower the tube current or the exposure time",
                 100 * saturated_fraction, c.saturation_counts,
                 !o.saturation_named.empty()         ? o.saturation_named.c_str()
                 : c.saturation_source == "observed" ? "the largest raw value"
                 : c.saturation_source == "bits"     ? "--bits"
                                                     : "--saturation",
                 100 * o.max_saturated_fraction));
    // After the saturation check: a flood saturated everywhere is identical too, and says so.
    LFTRACK_RETURN_IF_ERROR(check_not_frozen(flood, "flood", o.flood_names));
    const double nf = static_cast<double>(flood.size());
    for (std::size_t i = 0; i < n; ++i) signal[i] = static_cast<float>(static_cast<double>(sum[i]) / nf - offset[i]);
    c.defective = tracking::Image<unsigned char>(rows, cols, 0);
    for (std::size_t i = 0; i < n; ++i) c.defective.pixels()[i] = brightest[i] >= level;  // saturated, for now
  }

  const Robust all_signal = robust(signal);
  if (!(all_signal.median > o.min_signal_counts))
    return invalid_argument(format("the flood is no brighter than the dark: the median of flood - dark is %.1f counts "
                                   "(it must exceed %g); were the dark and flood folders swapped, or the beam off?",
                                   all_signal.median, o.min_signal_counts));
  std::size_t unlit = 0;
  for (float s : signal) unlit += !(s > 0);
  if (static_cast<double>(unlit) > o.max_unlit_fraction * static_cast<double>(n))
    return invalid_argument(format("%zu of %zu pixels (%.1f %%) are no brighter in the flood than in the dark (at most "
                                   "%.1f %% allowed): is the field open over the whole panel, were the folders mixed?",
                                   unlit, n, 100.0 * double(unlit) / double(n), 100 * o.max_unlit_fraction));

  const Robust dark_level = robust(offset), noise_level = robust(noise);
  c.offset_median_counts = dark_level.median;
  c.noise_median_counts = noise_level.median;
  // Frames that all differ, yet hold most pixels still: a detector frozen but for a few pixels.
  if (!(noise_level.median > 0))
    return invalid_argument("the dark frames have no temporal noise at most pixels (median 0 counts): a detector's "
                            "dark frames differ by their noise, so these are a frozen detector's or copies; take the "
                            "frames again");
  const double dark_limit = o.dark_sd * std::max(dark_level.sd, 1.0);
  const double noise_limit = o.noise_sd * std::max(noise_level.sd, 0.5);
  std::vector<unsigned char> bad(n, 0);
  std::vector<float> relative(n);  // signal / median signal of all pixels
  for (std::size_t i = 0; i < n; ++i) {
    const auto count = [&](bool broken, int rule) {
      if (!broken) return;
      ++c.defects_by_rule[std::size_t(rule)];
      bad[i] = 1;
    };
    relative[i] = static_cast<float>(signal[i] / all_signal.median);
    count(std::abs(offset[i] - dark_level.median) > dark_limit, kDefectDark);
    count(noise[i] - noise_level.median > noise_limit, kDefectNoise);
    count(!(relative[i] >= o.gain_low && relative[i] <= o.gain_high), kDefectGain);
    count(c.defective.pixels()[i] != 0, kDefectSaturated);
  }

  // Whole lines: a row or column whose median signal is off, or mostly defective already.
  std::vector<unsigned char> in_line(n, 0);
  std::vector<float> line;
  const auto judge_line = [&](int length, auto&& index) {
    line.clear();
    std::size_t broken = 0;
    for (int k = 0; k < length; ++k) {
      line.push_back(relative[index(k)]);
      broken += bad[index(k)];
    }
    const double m = median_of(&line);
    if (!(m >= o.line_low && m <= o.line_high) ||
        static_cast<double>(broken) > o.line_defect_fraction * static_cast<double>(length))
      for (int k = 0; k < length; ++k) in_line[index(k)] = 1;
  };
  for (int r = 0; r < rows; ++r) judge_line(cols, [&](int k) { return std::size_t(r) * std::size_t(cols) + std::size_t(k); });
  for (int k = 0; k < cols; ++k) judge_line(rows, [&](int r) { return std::size_t(r) * std::size_t(cols) + std::size_t(k); });
  for (std::size_t i = 0; i < n; ++i) {
    c.defects_by_rule[kDefectLine] += in_line[i];
    bad[i] |= in_line[i];
    c.defects += bad[i];
  }
  if (static_cast<std::size_t>(c.defects) > n / 2)
    return invalid_argument("more than half the pixels are defective (" + std::to_string(c.defects) + " of " +
                            std::to_string(n) + "): not a detector this rule can calibrate");

  // The open field over the good pixels, then the gain against it.
  std::vector<float> good;
  good.reserve(n);
  for (std::size_t i = 0; i < n; ++i)
    if (!bad[i]) good.push_back(signal[i]);
  c.open_field_counts = median_of(&good);
  if (!(std::isfinite(c.open_field_counts) && c.open_field_counts > 0))
    return internal_error("detector calibration: an open field of " + std::to_string(c.open_field_counts) + " counts");
  c.offset_counts = tracking::Image<float>(rows, cols);
  c.noise_counts = tracking::Image<float>(rows, cols);
  c.gain = tracking::Image<float>(rows, cols);
  for (std::size_t i = 0; i < n; ++i) {
    c.offset_counts.pixels()[i] = offset[i];
    c.noise_counts.pixels()[i] = noise[i];
    c.gain.pixels()[i] = static_cast<float>(std::max(0.0, signal[i] / c.open_field_counts));
    c.defective.pixels()[i] = bad[i];
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
  mix(&c.rows, sizeof c.rows);
  mix(&c.cols, sizeof c.cols);
  const auto mix_map = [&](const auto& image) {
    const auto& v = image.pixels();
    mix(v.data(), v.size() * sizeof(v[0]));
  };
  mix_map(c.offset_counts);
  mix_map(c.noise_counts);
  mix_map(c.gain);
  mix_map(c.defective);
  mix(&c.open_field_counts, sizeof c.open_field_counts);
  mix(&c.saturation_counts, sizeof c.saturation_counts);
  const std::uint64_t name_size = c.detector.size();
  mix(&name_size, sizeof name_size);
  mix(c.detector.data(), c.detector.size());
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(h));
  return hex;
}

tracking::DetectorCorrection to_detector_correction(const DetectorCalibration& c) {
  tracking::DetectorCorrection d;
  d.dark_counts = c.offset_counts;
  d.gain = c.gain;
  const std::size_t n = std::min(d.gain.pixels().size(), c.defective.pixels().size());
  for (std::size_t i = 0; i < n; ++i)
    if (c.defective.pixels()[i]) d.gain.pixels()[i] = 0.f;
  d.open_field_counts = c.open_field_counts;
  d.saturation_counts = c.saturation_counts;
  return d;
}

}  // namespace lftrack::calib
