// Mutual information (mi) and normalised mutual information (nmi) from a joint histogram with
// partial-volume binning of the moving image (similarity.hpp states the contract).
//
// The histogram holds integers: each usable pixel adds 2^weight_bits, split between the moving
// value's two nearest bins by its linear weight rounded to a multiple of 2^-weight_bits (16 bits
// up to 65,535 pixels; scores agree with a double-precision histogram to about 1e-6). Integer
// sums do not depend on the order of the additions, so the score is the same bit for bit whatever
// the pass structure, and the additions of an image of more than 4,096 pixels go to four
// sub-histograms: neighbouring pixels, which often fall in the same cell, then update different
// memory and do not wait on each other's store. A smaller image's score is set by clearing and
// scanning the cells, so it uses one.
//
// A score is two passes over the pixels, in AVX2 lanes where the CPU has them
// (mutual_information_kernels.cpp): the moving range, then each pixel's cell and weight
// (unusable pixels go to a spare row that is never read) added into the sub-histograms; then the
// entropies from the non-empty cells. prepare() bins the fixed image by two such passes too.

#include "mutual_information.hpp"

#include <algorithm>
#include <bit>
#include <cstddef>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "mutual_information_kernels.hpp"

namespace lftrack::tracking {
namespace {

double count_log_count(double k) { return k > 0 ? k * std::log(k) : 0.0; }

class MutualInformation final : public Similarity {
 public:
  MutualInformation(int bins, bool normalised, bool vector_lanes)
      : bins_(std::clamp(bins, 2, 1024)), normalised_(normalised), avx2_(vector_lanes && mi_avx2_available()) {}
  std::string_view name() const override { return normalised_ ? "nmi" : "mi"; }
  double worst_score() const override { return normalised_ ? 1.0 : 0.0; }

  Status prepare(const ImageView<const float>& f, const ImageView<const unsigned char>& v) override {
    if (f.empty()) return invalid_argument("similarity: the fixed image is empty");
    if (!v.empty() && (v.rows != f.rows || v.cols != f.cols))
      return invalid_argument("similarity: the fixed mask's size differs from the image's");
    rows_ = f.rows;
    cols_ = f.cols;
    const std::size_t pixels = std::size_t(rows_) * std::size_t(cols_);
    // Rows of bins_ counts, one per fixed bin, and a spare row for the unusable pixels.
    row_stride_ = std::uint32_t(bins_);
    unusable_row_ = std::uint32_t(bins_) * row_stride_;
    histogram_stride_ = std::size_t(bins_ + 1) * row_stride_;
    // The usable pixels' range (finite, and the mask's), by the moving range's pass on the fixed
    // image alone (no fixed rows: only the mask and the value decide).
    fixed_row_.resize(pixels);
    std::int32_t lo_key = std::numeric_limits<std::int32_t>::max(), hi_key = std::numeric_limits<std::int32_t>::min();
    for (int r = 0; r < rows_; ++r)
      mi_moving_range(MiRow{f.row_ptr(r), v.empty() ? nullptr : v.row_ptr(r), nullptr, cols_}, unusable_row_, &lo_key,
                      &hi_key, avx2_);
    const bool any_usable = lo_key <= hi_key;
    const float lo = any_usable ? mi_from_order_key(lo_key) : 0.f, hi = any_usable ? mi_from_order_key(hi_key) : 0.f;
    const double scale = hi > lo ? (bins_ - 1e-9) / (double(hi) - lo) : 0.0;
    for (int r = 0; r < rows_; ++r)
      mi_fixed_rows(f.row_ptr(r), v.empty() ? nullptr : v.row_ptr(r), cols_, lo, scale, bins_ - 1, row_stride_,
                    unusable_row_, &fixed_row_[std::size_t(r) * std::size_t(cols_)], avx2_);
    // No count may reach 2^32: the pixels times the unit stay below it.
    const int pixel_bits = static_cast<int>(std::bit_width(pixels));
    weight_bits_ = std::clamp(32 - pixel_bits, 1, 16);
    copies_ = pixels > std::size_t(kMiManyPixels) ? kMiSubHistograms : 1;
    histograms_.assign(std::size_t(copies_) * histogram_stride_, 0);
    moving_marginal_.assign(std::size_t(bins_ + 1), 0.0);
    return {};
  }

  double score(const ImageView<const float>& m, const ImageView<const unsigned char>& mv) override {
    if (m.rows != rows_ || m.cols != cols_ || m.data == nullptr || rows_ == 0 ||
        (!mv.empty() && (mv.rows != rows_ || mv.cols != cols_)))
      return worst_score();
    auto image_row = [&](int r) {
      return MiRow{m.row_ptr(r), mv.empty() ? nullptr : mv.row_ptr(r), &fixed_row_[std::size_t(r) * std::size_t(cols_)],
                   cols_};
    };
    std::int32_t lo_key = std::numeric_limits<std::int32_t>::max(), hi_key = std::numeric_limits<std::int32_t>::min();
    int n = 0;
    // Contiguous images are one long row (no tail per row for the lanes).
    const bool contiguous = m.stride == cols_ && (mv.empty() || mv.stride == cols_);
    const MiRow whole{m.data, mv.empty() ? nullptr : mv.data, fixed_row_.data(), rows_ * cols_};
    if (contiguous)
      n = mi_moving_range(whole, unusable_row_, &lo_key, &hi_key, avx2_);
    else
      for (int r = 0; r < rows_; ++r) n += mi_moving_range(image_row(r), unusable_row_, &lo_key, &hi_key, avx2_);
    if (n < kMinPixels) return worst_score();
    const float lo = mi_from_order_key(lo_key), hi = mi_from_order_key(hi_key);
    if (!(double(hi) - lo > 1e-12 * std::max(1.0, std::abs(double(hi))))) return worst_score();  // constant
    const std::uint32_t unit = std::uint32_t{1} << weight_bits_;
    MiBinning binning;
    binning.unusable_row = unusable_row_;
    binning.lo = lo;
    binning.scale = float((bins_ - 1) / (double(hi) - lo));
    binning.last_bin = bins_ - 2;
    binning.top = float(bins_ - 1);
    binning.weight_unit = float(unit);
    binning.weight_max = int(unit);
    binning.unit = unit;
    std::fill(histograms_.begin(), histograms_.end(), std::uint64_t{0});
    const MiHistograms histograms{histograms_.data(), copies_};
    if (contiguous)
      mi_accumulate(whole, binning, histograms, avx2_);
    else
      for (int r = 0; r < rows_; ++r) mi_accumulate(image_row(r), binning, histograms, avx2_);
    // The sub-histograms summed in place, cell k into word k (it reads words k * copies_ and on,
    // never below k; no half carries: every count stays below 2^32).
    std::uint64_t* joint = histograms_.data();
    if (copies_ > 1)
      for (std::size_t k = 0; k < unusable_row_; ++k) {
        const std::uint64_t* copies = joint + k * std::size_t(copies_);
        std::uint64_t sum = copies[0];
        for (int s = 1; s < copies_; ++s) sum += copies[s];
        joint[k] = sum;
      }
    // Entropies from sum(k ln k) over the non-empty cells: H = ln N - sum(k ln k) / N, N = n * unit.
    std::fill(moving_marginal_.begin(), moving_marginal_.end(), 0.0);
    double joint_sum = 0, fixed_sum = 0, moving_sum = 0;
    for (int a = 0; a < bins_; ++a) {
      const std::uint64_t* row = joint + std::size_t(a) * row_stride_;
      double fixed_count = 0;
      std::uint64_t upper = 0;  // the previous cell's upper-bin count
      for (int b = 0; b < bins_; ++b) {
        // Runs of empty words (most of a joint histogram) skipped eight at a time.
        while (upper == 0 && b + 8 <= bins_ &&
               (row[b] | row[b + 1] | row[b + 2] | row[b + 3] | row[b + 4] | row[b + 5] | row[b + 6] | row[b + 7]) == 0)
          b += 8;
        if (b >= bins_) break;
        const std::uint64_t k = (row[b] & 0xffffffffu) + upper;
        upper = row[b] >> 32;
        if (k == 0) continue;
        const double count = double(k);
        joint_sum += count * std::log(count);
        fixed_count += count;
        moving_marginal_[std::size_t(b)] += count;
      }
      fixed_sum += count_log_count(fixed_count);
    }
    for (int b = 0; b < bins_; ++b) moving_sum += count_log_count(moving_marginal_[std::size_t(b)]);
    const double total = double(n) * double(unit), log_total = std::log(total);
    const double h_fixed = log_total - fixed_sum / total, h_moving = log_total - moving_sum / total,
                 h_joint = log_total - joint_sum / total;
    if (normalised_) return h_joint > 1e-12 ? std::clamp((h_fixed + h_moving) / h_joint, 1.0, 2.0) : 1.0;
    return std::max(0.0, h_fixed + h_moving - h_joint);
  }
  std::unique_ptr<Similarity> clone() const override { return std::make_unique<MutualInformation>(*this); }

 private:
  int bins_;
  bool normalised_;
  bool avx2_;
  int rows_ = 0, cols_ = 0;
  int weight_bits_ = 16;
  int copies_ = kMiSubHistograms;  // sub-histograms (MiHistograms::copies), by the image's size
  std::uint32_t row_stride_ = 0, unusable_row_ = 0;
  std::size_t histogram_stride_ = 0;
  std::vector<std::uint32_t> fixed_row_;  // per pixel: its fixed bin's row offset, or the spare row
  // Scratch of score(): the sub-histograms (MiHistograms), the moving marginal.
  std::vector<std::uint64_t> histograms_;
  std::vector<double> moving_marginal_;
};

}  // namespace

std::unique_ptr<Similarity> make_mutual_information(int bins, bool normalised, bool vector_lanes) {
  return std::make_unique<MutualInformation>(bins, normalised, vector_lanes);
}

}  // namespace lftrack::tracking
