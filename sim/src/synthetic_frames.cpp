#include "lftrack/sim/synthetic_frames.hpp"

#include <algorithm>
#include <cmath>
#include <random>

namespace lftrack::sim {

using namespace lftrack::tracking;

DetectorCorrection detector_correction(const DetectorModel& model) {
  DetectorCorrection c;
  const double full_scale = std::ldexp(1.0, std::clamp(model.bits, 8, 16)) - 1;
  c.open_field_counts = model.open_field_fraction * full_scale;
  c.saturation_counts = static_cast<int>(full_scale);
  return c;
}

Result<Image<std::uint16_t>> synthesize_frame(const DrrRenderer& exact, const Pose& gold, const XrayView& view,
                                              const PixelWindow& window, const DetectorModel& model,
                                              std::uint64_t seed) {
  if (!(model.photons_per_pixel > 0) || !(model.open_field_fraction > 0 && model.open_field_fraction <= 1) ||
      model.bits < 8 || model.bits > 16)
    return invalid_argument("synthetic frame: photons > 0, open-field fraction in (0, 1], 8-16 bits");
  Image<float> line_integral(window.rows, window.cols);
  LFTRACK_RETURN_IF_ERROR(exact.render(gold, view, window, line_integral.view()));
  // Photons, with Poisson noise.
  std::mt19937_64 rng(seed);
  Image<float> photons(window.rows, window.cols);
  for (int r = 0; r < window.rows; ++r) {
    for (int c = 0; c < window.cols; ++c) {
      const double expected = model.photons_per_pixel * std::exp(-double(line_integral.at(r, c)));
      if (model.noise) {
        std::poisson_distribution<long> poisson(expected);
        photons.at(r, c) = static_cast<float>(poisson(rng));
      } else {
        photons.at(r, c) = static_cast<float>(expected);
      }
    }
  }
  // Detector blur, then quantisation.
  Image<float> blurred(window.rows, window.cols);
  GaussianBlur blur(window.rows, window.cols, model.blur_sigma_px);
  LFTRACK_RETURN_IF_ERROR(blur.blur(photons.view(), {}, blurred.view()));
  const DetectorCorrection correction = detector_correction(model);
  const double counts_per_photon = correction.open_field_counts / model.photons_per_pixel;
  Image<std::uint16_t> frame(view.rows, view.cols, 0);
  for (int r = 0; r < window.rows; ++r)
    for (int c = 0; c < window.cols; ++c)
      frame.at(window.row0 + r, window.col0 + c) = static_cast<std::uint16_t>(
          std::clamp(std::lround(blurred.at(r, c) * counts_per_photon), 0L, long(correction.saturation_counts)));
  return frame;
}

template <class Unit>
void insert_markers(ScalarVolume<Unit>* volume, const std::vector<Eigen::Vector3d>& centres, double radius_mm,
                    float marker_value) {
  const VolumeGeometry& g = volume->geometry;
  const Eigen::Affine3d index_from_ct = g.index_from_ct();
  const Eigen::Affine3d ct_from_index = g.ct_from_index();
  constexpr int kSub = 4;
  for (const Eigen::Vector3d& centre : centres) {
    const Eigen::Vector3d ci = index_from_ct * centre;
    const Eigen::Vector3d reach = (radius_mm + 1e-9) * g.spacing_mm.cwiseInverse() + Eigen::Vector3d::Constant(1);
    Eigen::Vector3i lo, hi;
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::max(0, int(std::floor(ci[a] - reach[a])));
      hi[a] = std::min(g.size[a] - 1, int(std::ceil(ci[a] + reach[a])));
    }
    for (int k = lo.z(); k <= hi.z(); ++k)
      for (int j = lo.y(); j <= hi.y(); ++j)
        for (int i = lo.x(); i <= hi.x(); ++i) {
          int inside = 0;
          for (int a = 0; a < kSub; ++a)
            for (int b = 0; b < kSub; ++b)
              for (int c = 0; c < kSub; ++c) {
                const Eigen::Vector3d sub(i + (a + 0.5) / kSub - 0.5, j + (b + 0.5) / kSub - 0.5,
                                          k + (c + 0.5) / kSub - 0.5);
                if ((ct_from_index * sub - centre).norm() <= radius_mm) ++inside;
              }
          if (inside == 0) continue;
          const float share = float(inside) / float(kSub * kSub * kSub);
          float& v = volume->at(i, j, k);
          v = (1 - share) * v + share * marker_value;
        }
  }
}

template void insert_markers(ScalarVolume<HounsfieldUnits>*, const std::vector<Eigen::Vector3d>&, double, float);
template void insert_markers(ScalarVolume<AttenuationPerMm>*, const std::vector<Eigen::Vector3d>&, double, float);

}  // namespace lftrack::sim
