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

namespace {

// More photons per pixel than this is no X-ray detector (a 16-bit panel saturates far below it);
// std::poisson_distribution spins without end on means near 1e25 (an outside probe's
// `photons_per_pixel: 1e40` ignored SIGTERM).
constexpr double kMaxPhotonsPerPixel = 1e9;

Status check_model(const DetectorModel& model) {
  if (!(model.photons_per_pixel > 0 && model.photons_per_pixel <= kMaxPhotonsPerPixel) ||
      !(model.open_field_fraction > 0 && model.open_field_fraction <= 1) || model.bits < 8 || model.bits > 16)
    return invalid_argument("synthetic frame: photons in (0, 1e9], open-field fraction in (0, 1], 8-16 bits");
  return {};
}

}  // namespace

FrameSynthesizer::FrameSynthesizer(const PixelWindow& window, const DetectorModel& model)
    : window_(window),
      model_(model),
      line_integral_(window.rows, window.cols),
      photons_(window.rows, window.cols),
      blurred_(window.rows, window.cols),
      blur_(window.rows, window.cols, model.blur_sigma_px) {}

Status FrameSynthesizer::synthesize(const DrrRenderer& renderer, const Pose& gold, const XrayView& view,
                                    std::uint64_t seed, ImageView<std::uint16_t> frame) {
  LFTRACK_RETURN_IF_ERROR(check_model(model_));
  if (frame.rows != view.rows || frame.cols != view.cols || !window_.inside(view.rows, view.cols))
    return invalid_argument("synthetic frame: the frame must be the whole detector, the window inside it");
  LFTRACK_RETURN_IF_ERROR(renderer.render(gold, view, window_, line_integral_.view()));
  // Photons, with Poisson noise.
  std::mt19937_64 rng(seed);
  for (int r = 0; r < window_.rows; ++r) {
    for (int c = 0; c < window_.cols; ++c) {
      const double expected = model_.photons_per_pixel * std::exp(-double(line_integral_.at(r, c)));
      if (model_.noise) {
        std::poisson_distribution<long> poisson(expected);
        photons_.at(r, c) = static_cast<float>(poisson(rng));
      } else {
        photons_.at(r, c) = static_cast<float>(expected);
      }
    }
  }
  // Detector blur, then quantisation.
  LFTRACK_RETURN_IF_ERROR(blur_.blur(photons_.view(), {}, blurred_.view()));
  const DetectorCorrection correction = detector_correction(model_);
  const double counts_per_photon = correction.open_field_counts / model_.photons_per_pixel;
  for (int r = 0; r < window_.rows; ++r)
    for (int c = 0; c < window_.cols; ++c)
      frame.at(window_.row0 + r, window_.col0 + c) = static_cast<std::uint16_t>(std::clamp(
          std::lround(blurred_.at(r, c) * counts_per_photon), 0L, long(correction.saturation_counts)));
  return {};
}

Result<Image<std::uint16_t>> synthesize_frame(const DrrRenderer& exact, const Pose& gold,
                                              const XrayView& view, const PixelWindow& window,
                                              const DetectorModel& model, std::uint64_t seed) {
  LFTRACK_RETURN_IF_ERROR(check_model(model));
  Image<std::uint16_t> frame(view.rows, view.cols, 0);
  FrameSynthesizer synthesizer(window, model);
  LFTRACK_RETURN_IF_ERROR(synthesizer.synthesize(exact, gold, view, seed, frame.view()));
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
    const Eigen::Vector3d reach =
        (radius_mm + 1e-9) * g.spacing_mm.cwiseInverse() + Eigen::Vector3d::Constant(1);
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

template void insert_markers(ScalarVolume<HounsfieldUnits>*, const std::vector<Eigen::Vector3d>&, double,
                             float);
template void insert_markers(ScalarVolume<AttenuationPerMm>*, const std::vector<Eigen::Vector3d>&, double,
                             float);

}  // namespace lftrack::sim
