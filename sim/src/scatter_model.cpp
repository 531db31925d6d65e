#include "lftrack/sim/scatter_model.hpp"

#include <algorithm>
#include <cmath>

namespace lftrack::sim {

using sim_spec::ScatterSpec;

using tracking::ImageView;

namespace {
int coarse_factor(double sigma_px) { return std::clamp(int(sigma_px / 4), 1, 64); }
}  // namespace

ScatterModel::ScatterModel(int rows, int cols, double pitch_mm, const ScatterSpec& spec)
    : spec_(spec),
      rows_(rows),
      cols_(cols),
      factor_(coarse_factor(spec.kernel_sigma_mm / pitch_mm)),
      coarse_rows_((rows + factor_ - 1) / factor_),
      coarse_cols_((cols + factor_ - 1) / factor_),
      coarse_amplitude_(coarse_rows_, coarse_cols_),
      coarse_weight_(coarse_rows_, coarse_cols_),
      coarse_scatter_(coarse_rows_, coarse_cols_),
      coarse_valid_(coarse_rows_, coarse_cols_, 1),  // every block is exposed
      blur_(coarse_rows_, coarse_cols_, spec.kernel_sigma_mm / pitch_mm / factor_) {}

double ScatterModel::measured_spr(double thickness_cm) const {
  const double spr = spec_.spr_per_cm * std::max(0.0, thickness_cm);
  return spec_.grid ? spr * spec_.grid_scatter_transmission / spec_.grid_primary_transmission : spr;
}

double ScatterModel::photon_fraction() const { return spec_.grid ? spec_.grid_primary_transmission : 1.0; }

Status ScatterModel::add_scatter(const ImageView<const float>& primary, const ImageView<const float>& thickness,
                                 ImageView<float> out) {
  if (primary.rows != rows_ || primary.cols != cols_ || thickness.rows != rows_ || thickness.cols != cols_ ||
      out.rows != rows_ || out.cols != cols_)
    return invalid_argument("scatter: images of the wrong size");
  // Block means of the scattering amplitude primary x SPR(t) (measured, after the grid).
  std::fill(coarse_amplitude_.pixels().begin(), coarse_amplitude_.pixels().end(), 0.f);
  std::fill(coarse_weight_.pixels().begin(), coarse_weight_.pixels().end(), 0.f);
  for (int r = 0; r < rows_; ++r)
    for (int c = 0; c < cols_; ++c) {
      const float p = primary.at(r, c), t = thickness.at(r, c);
      const double a = (std::isfinite(p) && p > 0 ? p : 0.f) * measured_spr(std::isfinite(t) ? t : 0.0);
      coarse_amplitude_.at(r / factor_, c / factor_) += float(a);
      coarse_weight_.at(r / factor_, c / factor_) += 1.f;
    }
  for (int r = 0; r < coarse_rows_; ++r)
    for (int c = 0; c < coarse_cols_; ++c) coarse_amplitude_.at(r, c) /= coarse_weight_.at(r, c);
  LFTRACK_RETURN_IF_ERROR(blur_.blur(coarse_amplitude_.view(), coarse_valid_.view(), coarse_scatter_.view()));
  // Back to full resolution, bilinear between block centres (clamped at the edges).
  for (int r = 0; r < rows_; ++r) {
    const double fr = std::clamp((r + 0.5) / factor_ - 0.5, 0.0, double(coarse_rows_ - 1));
    const int r0 = std::min(int(fr), coarse_rows_ - 1), r1 = std::min(r0 + 1, coarse_rows_ - 1);
    const float tr = float(fr - r0);
    for (int c = 0; c < cols_; ++c) {
      const double fc = std::clamp((c + 0.5) / factor_ - 0.5, 0.0, double(coarse_cols_ - 1));
      const int c0 = std::min(int(fc), coarse_cols_ - 1), c1 = std::min(c0 + 1, coarse_cols_ - 1);
      const float tc = float(fc - c0);
      const float s = (1 - tr) * ((1 - tc) * coarse_scatter_.at(r0, c0) + tc * coarse_scatter_.at(r0, c1)) +
                      tr * ((1 - tc) * coarse_scatter_.at(r1, c0) + tc * coarse_scatter_.at(r1, c1));
      out.at(r, c) = primary.at(r, c) + s;
    }
  }
  return {};
}

}  // namespace lftrack::sim
