#pragma once
// A fixed-bin histogram for the loop's running statistics: sized once, add() allocates nothing,
// so an unbounded run keeps quantiles of every cycle. Values above the range land in the last
// bin (and max() still reports them exactly); quantiles are accurate to one bin width.

#include <algorithm>
#include <cstdint>
#include <vector>

namespace lftrack::loop {

class Histogram {
 public:
  Histogram(double bin_width, double max_value)
      : width_(bin_width), counts_(static_cast<std::size_t>(max_value / bin_width) + 1, 0) {}

  void add(double value) {
    if (!(value >= 0)) value = 0;  // NaN and negatives count as 0 (they are reported elsewhere)
    const std::size_t bin = std::min(counts_.size() - 1, static_cast<std::size_t>(value / width_));
    ++counts_[bin];
    ++n_;
    sum_ += value;
    max_ = std::max(max_, value);
  }
  std::uint64_t count() const { return n_; }
  double mean() const { return n_ > 0 ? sum_ / double(n_) : 0.0; }
  double max() const { return max_; }
  // The upper edge of the bin holding the q-quantile (0 for an empty histogram), capped at max().
  double quantile(double q) const {
    if (n_ == 0) return 0;
    const double rank = std::clamp(q, 0.0, 1.0) * double(n_);
    std::uint64_t seen = 0;
    for (std::size_t i = 0; i < counts_.size(); ++i) {
      seen += counts_[i];
      if (double(seen) >= rank && seen > 0) return std::min(max_, double(i + 1) * width_);
    }
    return max_;
  }

 private:
  double width_;
  std::vector<std::uint64_t> counts_;
  std::uint64_t n_ = 0;
  double sum_ = 0;
  double max_ = 0;
};

}  // namespace lftrack::loop
