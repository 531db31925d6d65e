#include "lftrack/tracking/image_metrics.hpp"

#include <cmath>
#include <limits>

namespace lftrack::tracking {
namespace {

bool same_shape(const ImageView<const float>& a, const ImageView<const float>& b,
                const ImageView<const unsigned char>* mask) {
  if (a.rows != b.rows || a.cols != b.cols || a.empty()) return false;
  return !mask || (mask->rows == a.rows && mask->cols == a.cols);
}

}  // namespace

double normalized_cross_correlation(const ImageView<const float>& a, const ImageView<const float>& b,
                                    const ImageView<const unsigned char>* mask) {
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  if (!same_shape(a, b, mask)) return kNaN;
  double n = 0, sa = 0, sb = 0;
  for (int r = 0; r < a.rows; ++r)
    for (int c = 0; c < a.cols; ++c) {
      if (mask && !mask->at(r, c)) continue;
      n += 1;
      sa += a.at(r, c);
      sb += b.at(r, c);
    }
  if (n == 0) return kNaN;
  const double ma = sa / n, mb = sb / n;
  double saa = 0, sbb = 0, sab = 0;
  for (int r = 0; r < a.rows; ++r)
    for (int c = 0; c < a.cols; ++c) {
      if (mask && !mask->at(r, c)) continue;
      const double da = a.at(r, c) - ma, db = b.at(r, c) - mb;
      saa += da * da;
      sbb += db * db;
      sab += da * db;
    }
  if (!std::isfinite(saa + sbb + sab)) return kNaN;
  if (saa == 0 || sbb == 0) return (saa == 0 && sbb == 0 && ma == mb) ? 1.0 : 0.0;
  return sab / std::sqrt(saa * sbb);
}

double psnr_db(const ImageView<const float>& ref, const ImageView<const float>& test,
               const ImageView<const unsigned char>* mask) {
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  if (!same_shape(ref, test, mask)) return kNaN;
  double n = 0, se = 0, peak = 0;
  for (int r = 0; r < ref.rows; ++r)
    for (int c = 0; c < ref.cols; ++c) {
      if (mask && !mask->at(r, c)) continue;
      const double e = double(test.at(r, c)) - ref.at(r, c);
      se += e * e;
      peak = std::max(peak, std::abs(double(ref.at(r, c))));
      n += 1;
    }
  if (n == 0 || !std::isfinite(se)) return kNaN;
  if (se == 0) return std::numeric_limits<double>::infinity();
  return 20.0 * std::log10(peak / std::sqrt(se / n));
}

}  // namespace lftrack::tracking
