#pragma once
// Figures of merit for comparing two images of the same size. Both ignore pixels where `mask`
// (optional, same size) is 0. Non-finite pixels in either image make the result NaN, so that a
// comparison never looks good by accident.

#include <optional>

#include "lftrack/tracking/image.hpp"

namespace lftrack::tracking {

// Normalised cross-correlation in [-1, 1]: invariant to any linear intensity map a*x + b with
// a > 0. Two constant images give 1 if equal, else 0.
double normalized_cross_correlation(const ImageView<const float>& a, const ImageView<const float>& b,
                                    const ImageView<const unsigned char>* mask = nullptr);

// Peak signal-to-noise ratio of `test` against `reference` in dB, the peak being the largest
// absolute value of the reference: 20 log10(peak / RMSE). Identical images give +infinity.
double psnr_db(const ImageView<const float>& reference, const ImageView<const float>& test,
               const ImageView<const unsigned char>* mask = nullptr);

}  // namespace lftrack::tracking
