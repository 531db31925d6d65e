#include "lftrack/sim/phantom_images.hpp"

#include <cmath>
#include <random>
#include <vector>

#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/frame_preprocessing.hpp"

namespace lftrack::sim {

namespace {

// Length of the segment of the line o + t d (|d| = 1) inside the axis-aligned box |x| <= h.
double box_chord(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Eigen::Vector3d& half) {
  double t0 = -1e300, t1 = 1e300;
  for (int k = 0; k < 3; ++k) {
    if (std::abs(d(k)) < 1e-15) {
      if (std::abs(o(k)) > half(k)) return 0;
      continue;
    }
    double a = (-half(k) - o(k)) / d(k), b = (half(k) - o(k)) / d(k);
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
  }
  return t1 > t0 ? t1 - t0 : 0.0;
}

}  // namespace

Result<tracking::Image<float>> render_phantom_image(const calib::CalibrationPhantom& phantom,
                                                    const Eigen::Isometry3d& T_view_from_phantom,
                                                    const tracking::XrayView& view,
                                                    const PhantomImageSpec& spec) {
  LFTRACK_RETURN_IF_ERROR(phantom.validate());
  LFTRACK_RETURN_IF_ERROR(view.validate());
  if (spec.supersample < 1 || spec.supersample > 16 ||
      !(spec.photons_per_pixel >= 0 && spec.photons_per_pixel <= sim_spec::kMaxPhotonsPerPixel) ||
      !(spec.blur_px >= 0)) {
    return invalid_argument("phantom image: supersample 1..16, photons 0..1e9, blur >= 0");
  }
  // Work in the phantom's frame.
  const tracking::XrayView v = view.transformed(T_view_from_phantom.inverse());
  const double radius = 0.5 * phantom.marker_diameter_mm;
  const bool has_body = (phantom.body_size_mm.array() > 0).all();
  const Eigen::Vector3d half = 0.5 * phantom.body_size_mm;
  // Each marker's projection and a generous reach in pixels, to skip far markers quickly.
  struct Near {
    Eigen::Vector3d centre;
    Eigen::Vector2d px;
    double reach_px;
  };
  std::vector<Near> markers;
  for (const Eigen::Vector3d& m : phantom.markers_mm) {
    const auto px = v.project(m);
    if (!px) continue;
    const double depth = v.detector_normal().dot(v.source_mm - m);
    const double magnification = v.source_to_detector_mm() / std::max(depth, 1e-6);
    markers.push_back({m, *px, radius * magnification / std::min(v.pitch_col_mm, v.pitch_row_mm) + 2});
  }
  tracking::Image<float> intensity(v.rows, v.cols);
  const int ss = spec.supersample;
  for (int r = 0; r < v.rows; ++r) {
    for (int c = 0; c < v.cols; ++c) {
      double sum = 0;
      for (int a = 0; a < ss; ++a) {
        for (int b = 0; b < ss; ++b) {
          const double rr = r - 0.5 + (a + 0.5) / ss, cc = c - 0.5 + (b + 0.5) / ss;
          const Eigen::Vector3d d = (v.pixel_centre_mm(rr, cc) - v.source_mm).normalized();
          double p = has_body ? phantom.body_mu_per_mm * box_chord(v.source_mm, d, half) : 0.0;
          for (const Near& m : markers) {
            if (std::abs(m.px.x() - cc) > m.reach_px || std::abs(m.px.y() - rr) > m.reach_px) continue;
            const Eigen::Vector3d to = m.centre - v.source_mm;
            const double along = to.dot(d);
            const double miss2 = to.squaredNorm() - along * along;
            if (miss2 < radius * radius) {
              const double chord = 2 * std::sqrt(radius * radius - miss2);
              p += (phantom.marker_mu_per_mm - (has_body ? phantom.body_mu_per_mm : 0.0)) * chord;
            }
          }
          sum += std::exp(-p);
        }
      }
      intensity.at(r, c) = float(sum / (ss * ss));
    }
  }
  tracking::Image<float> blurred(v.rows, v.cols);
  tracking::GaussianBlur blur(v.rows, v.cols, spec.blur_px);
  LFTRACK_RETURN_IF_ERROR(blur.blur(intensity.view(), {}, blurred.view()));
  std::mt19937_64 rng(spec.seed);
  std::normal_distribution<double> unit(0, 1);
  tracking::Image<float> out(v.rows, v.cols);
  for (int r = 0; r < v.rows; ++r) {
    for (int c = 0; c < v.cols; ++c) {
      double i = blurred.at(r, c);
      if (spec.photons_per_pixel > 0) {
        // Poisson counts, by the normal approximation (the mean is in the hundreds or more).
        const double mean = spec.photons_per_pixel * i;
        const double counts = std::max(1.0, mean + std::sqrt(mean) * unit(rng));
        i = counts / spec.photons_per_pixel;
      }
      out.at(r, c) = float(-std::log(std::max(i, 1e-12)));
    }
  }
  return out;
}

}  // namespace lftrack::sim
