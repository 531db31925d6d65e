#include "lftrack/calib/detector_qa.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>

namespace lftrack::calib {
namespace {

constexpr int kGridBlocks = 8;         // blocks per side of the uniformity grid, at most
constexpr int kMinBlockSide = 8;       // pixels
constexpr double kMinGoodShare = 0.5;  // of a block's pixels, for the block to count

bool in(double v, double lo, double hi) {
  return std::isfinite(v) && v >= lo && v <= hi;
}

double median_of(std::vector<double>* v) {
  if (v->empty()) return 0;
  const auto mid = v->begin() + static_cast<std::ptrdiff_t>(v->size() / 2);
  std::nth_element(v->begin(), mid, v->end());
  return *mid;
}

bool good(const DetectorCalibration& a, const DetectorCalibration& b, int r, int c) {
  return a.defective.at(r, c) == 0 && b.defective.at(r, c) == 0;
}

// What the loop makes of today's flood at (r, c): the flood's mean (today's offset plus its
// signal) less the baseline's offset, over the baseline's gain.
double corrected_flood(const DetectorCalibration& baseline, const DetectorCalibration& today, int r, int c) {
  const double flood = today.offset_counts.at(r, c) + today.gain.at(r, c) * today.open_field_counts;
  return (flood - baseline.offset_counts.at(r, c)) / baseline.gain.at(r, c);
}

// (largest - smallest) / mean of the block means of the corrected flood; `blocks` counted.
double block_nonuniformity(const DetectorCalibration& baseline, const DetectorCalibration& today,
                           int* blocks) {
  const int rows = baseline.rows, cols = baseline.cols;
  const int along_rows = std::clamp(rows / kMinBlockSide, 1, kGridBlocks);
  const int along_cols = std::clamp(cols / kMinBlockSide, 1, kGridBlocks);
  std::vector<double> means;
  for (int br = 0; br < along_rows; ++br)
    for (int bc = 0; bc < along_cols; ++bc) {
      const int r0 = br * rows / along_rows, r1 = (br + 1) * rows / along_rows;
      const int c0 = bc * cols / along_cols, c1 = (bc + 1) * cols / along_cols;
      double sum = 0;
      std::int64_t n = 0;
      for (int r = r0; r < r1; ++r)
        for (int c = c0; c < c1; ++c)
          if (good(baseline, today, r, c) && baseline.gain.at(r, c) > 0) {
            sum += corrected_flood(baseline, today, r, c);
            ++n;
          }
      if (double(n) >= kMinGoodShare * double((r1 - r0) * (c1 - c0))) means.push_back(sum / double(n));
    }
  *blocks = int(means.size());
  if (means.empty()) return 1;
  const auto [lo, hi] = std::minmax_element(means.begin(), means.end());
  double mean = 0;
  for (double m : means) mean += m / double(means.size());
  return mean > 0 ? (*hi - *lo) / mean : 1;
}

// Rows and columns of which more than `fraction` of the pixels are newly defective.
std::vector<std::string> new_lines(const DetectorCalibration& baseline, const DetectorCalibration& today,
                                   double fraction) {
  std::vector<int> per_row(std::size_t(baseline.rows), 0), per_col(std::size_t(baseline.cols), 0);
  for (int r = 0; r < baseline.rows; ++r)
    for (int c = 0; c < baseline.cols; ++c)
      if (today.defective.at(r, c) != 0 && baseline.defective.at(r, c) == 0) {
        ++per_row[std::size_t(r)];
        ++per_col[std::size_t(c)];
      }
  std::vector<std::string> lines;
  for (int r = 0; r < baseline.rows; ++r)
    if (per_row[std::size_t(r)] > fraction * baseline.cols) lines.push_back(fmt::format("row {}", r));
  for (int c = 0; c < baseline.cols; ++c)
    if (per_col[std::size_t(c)] > fraction * baseline.rows) lines.push_back(fmt::format("column {}", c));
  return lines;
}

}  // namespace

Status check_detector_qa_tolerances(const DetectorQaTolerances& t) {
  if (!in(t.max_dark_drift_fraction, 1e-9, 1))
    return invalid_argument("detector QA: the dark drift limit must be in (0, 1] of the open field");
  if (!in(t.max_noise_ratio, 1 + 1e-9, 1000))
    return invalid_argument("detector QA: the noise ratio limit must be above 1 (at most 1000)");
  if (!in(t.max_nonuniformity, 1e-9, 1))
    return invalid_argument("detector QA: the non-uniformity limit must be in (0, 1]");
  if (!in(t.max_new_defect_fraction, 0, 1))
    return invalid_argument("detector QA: the new-defect limit must be in [0, 1] of the pixels");
  if (t.min_frames < kMinQaFrames || t.min_frames > kMaxQaFrames)
    return invalid_argument(fmt::format("detector QA: the minimum of dark and flood frames must be {} to {}",
                                        kMinQaFrames, kMaxQaFrames));
  return {};
}

Result<DetectorQaResult> check_detector_quality(const DetectorCalibration& baseline,
                                                const std::vector<tracking::Image<std::uint16_t>>& dark,
                                                const std::vector<tracking::Image<std::uint16_t>>& flood,
                                                const DetectorQaTolerances& t) {
  LFTRACK_RETURN_IF_ERROR(check_detector_qa_tolerances(t));
  const auto sized = [&](const auto& map) {
    return map.rows() == baseline.rows && map.cols() == baseline.cols;
  };
  if (baseline.rows < kMinDetectorSide || baseline.cols < kMinDetectorSide ||
      !sized(baseline.offset_counts) || !sized(baseline.noise_counts) || !sized(baseline.gain) ||
      !sized(baseline.defective) || !(baseline.open_field_counts > 0))
    return invalid_argument("detector QA: the calibration holds no maps (was it made or loaded?)");
  for (const auto* frames : {&dark, &flood})
    for (const auto& f : *frames)
      if (f.rows() != baseline.rows || f.cols() != baseline.cols)
        return invalid_argument(fmt::format(
            "today's {} frames are {} x {} pixels; the calibration of detector '{}' is {} x {}: not this "
            "detector's frames, or its read-out mode changed",
            frames == &dark ? "dark" : "flood", f.cols(), f.rows(), baseline.detector, baseline.cols,
            baseline.rows));
  // Today's frames by the baseline's own rule and saturation level, so that a pixel is judged
  // by the thresholds that made the mask the loop uses.
  DetectorCalibrationOptions rule = baseline.rule;
  rule.min_dark_frames = rule.min_flood_frames = t.min_frames;
  rule.saturation_counts = baseline.saturation_counts;
  rule.saturation_named = "the calibration's saturation level";
  rule.dark_names.clear();
  rule.flood_names.clear();
  auto today = calibrate_detector(dark, flood, rule);
  if (!today.ok()) return today.status().with_context("today's frames");

  DetectorQaResult q;
  q.pixels = std::int64_t(baseline.rows) * baseline.cols;
  std::vector<double> drift;
  drift.reserve(std::size_t(q.pixels));
  // The noise as the root of the mean variance over the good pixels: a per-pixel variance from n
  // frames is unbiased whatever n, so today's 8 frames compare with the calibration's 16 (a
  // median of standard deviations is not: 0.95 sigma from 8 frames, 0.67 from 2).
  double variance_today = 0, variance_baseline = 0;
  for (int r = 0; r < baseline.rows; ++r)
    for (int c = 0; c < baseline.cols; ++c) {
      const bool was = baseline.defective.at(r, c) != 0, is = today->defective.at(r, c) != 0;
      if (is && !was) ++q.new_defects;
      if (was && !is) ++q.healed_defects;
      if (was || is) continue;
      drift.push_back(double(today->offset_counts.at(r, c)) - baseline.offset_counts.at(r, c));
      variance_today += double(today->noise_counts.at(r, c)) * today->noise_counts.at(r, c);
      variance_baseline += double(baseline.noise_counts.at(r, c)) * baseline.noise_counts.at(r, c);
    }
  if (drift.empty())
    return failed_precondition("no pixel is good both today and in the calibration: nothing to judge");
  q.dark_drift_counts = median_of(&drift);
  q.dark_drift_limit_counts = t.max_dark_drift_fraction * baseline.open_field_counts;
  q.noise_ratio = variance_baseline > 0 ? std::sqrt(variance_today / variance_baseline)
                                        : (variance_today > 0 ? INFINITY : 1);
  q.nonuniformity = block_nonuniformity(baseline, *today, &q.blocks);
  q.open_field_ratio = today->open_field_counts / baseline.open_field_counts;
  q.new_defect_limit = std::int64_t(std::floor(t.max_new_defect_fraction * double(q.pixels)));
  q.new_lines = new_lines(baseline, *today, baseline.rule.line_defect_fraction);

  q.measured = fmt::format(
      "dark drift {:+.1f} counts; noise x{:.2f}; non-uniformity {:.2f} % over {} blocks; {} new defects, {} "
      "healed{}; open field x{:.3f}",
      q.dark_drift_counts, q.noise_ratio, 100 * q.nonuniformity, q.blocks, q.new_defects, q.healed_defects,
      q.new_lines.empty() ? "" : fmt::format(" (new defective {})", fmt::join(q.new_lines, ", ")),
      q.open_field_ratio);
  // Each comparison is written so that a NaN fails it.
  if (!(std::abs(q.dark_drift_counts) <= q.dark_drift_limit_counts))
    q.why = fmt::format(
        "the dark level drifted {:+.1f} counts since the calibration, beyond {:.1f} ({} % of the "
        "open field): recalibrate the detector",
        q.dark_drift_counts, q.dark_drift_limit_counts, 100 * t.max_dark_drift_fraction);
  else if (!(q.noise_ratio <= t.max_noise_ratio))
    q.why =
        fmt::format("the temporal noise is x{:.2f} the calibration's, beyond x{}: the read-out electronics",
                    q.noise_ratio, t.max_noise_ratio);
  else if (!(q.noise_ratio >= 1 / t.max_noise_ratio))
    q.why = fmt::format(
        "the temporal noise is x{:.2f} the calibration's, below x1/{}: a read-out that no longer "
        "follows the signal (frozen or stuck), or frames averaged before they were saved",
        q.noise_ratio, t.max_noise_ratio);
  else if (q.blocks == 0 || !(q.nonuniformity <= t.max_nonuniformity))
    q.why = q.blocks == 0
                ? std::string("no block of the flood has enough good pixels to judge its uniformity")
                : fmt::format(
                      "the flood corrected by the calibration is {:.2f} % non-uniform, beyond "
                      "{} %: the gain drifted, or the flood was not taken as the calibration's "
                      "(distance, kV, filtration, an open field); recalibrate the detector",
                      100 * q.nonuniformity, 100 * t.max_nonuniformity);
  else if (!q.new_lines.empty())
    q.why = fmt::format("new defective {} not in the calibration's defect map: recalibrate the detector",
                        fmt::join(q.new_lines, ", "));
  else if (q.new_defects > q.new_defect_limit)
    q.why = fmt::format(
        "{} pixels are defective and not in the calibration's defect map, beyond {} ({} % of "
        "the pixels): recalibrate the detector",
        q.new_defects, q.new_defect_limit, 100 * t.max_new_defect_fraction);
  q.passed = q.why.empty();
  return q;
}

}  // namespace lftrack::calib
