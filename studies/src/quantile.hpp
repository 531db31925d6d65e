#pragma once
// Quantiles of small samples for reports (linear interpolation between order statistics).

#include <algorithm>
#include <cstddef>
#include <vector>

namespace lftrack::studies {

// q in [0, 1]; 0 for an empty sample.
inline double quantile(std::vector<double> values, double q) {
  if (values.empty()) return 0;
  std::sort(values.begin(), values.end());
  const double pos = std::clamp(q, 0.0, 1.0) * double(values.size() - 1);
  const std::size_t i = static_cast<std::size_t>(pos);
  return i + 1 < values.size() ? values[i] + (pos - double(i)) * (values[i + 1] - values[i]) : values[i];
}

}  // namespace lftrack::studies
