#pragma once
// Running sums for a correlation coefficient (the ncc similarity, the registration verdict's
// check of a frame against its DRR).

#include <algorithm>
#include <cmath>

namespace lftrack::tracking {

struct CorrelationSums {
  double n = 0, a = 0, b = 0, aa = 0, bb = 0, ab = 0;
  void add(double x, double y) {
    n += 1;
    a += x;
    b += y;
    aa += x * x;
    bb += y * y;
    ab += x * y;
  }
  // NCC; 0 when either side is constant.
  double value() const {
    if (n < 1) return 0;
    const double va = aa - a * a / n, vb = bb - b * b / n, cov = ab - a * b / n;
    const double denom = std::sqrt(std::max(va, 0.0) * std::max(vb, 0.0));
    if (!(denom > 1e-300) || !std::isfinite(denom)) return 0;
    return std::clamp(cov / denom, -1.0, 1.0);
  }
};

}  // namespace lftrack::tracking
