#include "lftrack/sim/sphere_markers.hpp"

#include <algorithm>
#include <cmath>
#include <string>

namespace lftrack::sim {
namespace {

class SphereMarkerRenderer final : public tracking::DrrRenderer {
 public:
  SphereMarkerRenderer(std::shared_ptr<const tracking::DrrRenderer> inner, std::vector<SphereMarker> markers,
                       int sub_rays)
      : inner_(std::move(inner)), markers_(std::move(markers)), sub_rays_(sub_rays) {}
  std::string_view name() const override { return inner_->name(); }
  std::size_t bytes() const override { return inner_->bytes(); }

 protected:
  Status do_render(const tracking::Pose& T, const tracking::XrayView& view, const tracking::PixelWindow& window,
                   tracking::ImageView<float> out, tracking::RenderExtras* extras) const override {
    LFTRACK_RETURN_IF_ERROR(inner_->render(T, view, window, out, extras));
    const double sub = 1.0 / sub_rays_;
    for (const SphereMarker& m : markers_) {
      const Eigen::Vector3d centre = T * m.centre_ct_mm;
      const auto projected = view.project(centre);
      if (!projected) continue;
      // Pixels the sphere's shadow can reach: its projected radius, magnified, plus a margin.
      const Eigen::Vector3d to_centre = centre - view.source_mm;
      const double distance = to_centre.norm();
      if (distance <= m.radius_mm) continue;  // the source inside a marker: nothing sensible to add
      const double magnification = view.source_to_detector_mm() / (distance - m.radius_mm);
      const double reach_px =
          m.radius_mm * magnification / std::min(view.pitch_col_mm, view.pitch_row_mm) + 2.0;
      // Clamped to the window in double before the cast: a sphere next to the source has an
      // enormous shadow, and a centre beside the source plane projects far off the detector.
      auto clamp_to = [](double v, int lo, int hi) { return int(std::clamp(v, double(lo), double(hi))); };
      const int last_row = window.row0 + window.rows - 1, last_col = window.col0 + window.cols - 1;
      const double lo_r = std::floor(projected->y() - reach_px), hi_r = std::ceil(projected->y() + reach_px);
      const double lo_c = std::floor(projected->x() - reach_px), hi_c = std::ceil(projected->x() + reach_px);
      if (!(hi_r >= window.row0 && lo_r <= last_row && hi_c >= window.col0 && lo_c <= last_col)) continue;
      const int r0 = clamp_to(lo_r, window.row0, last_row), r1 = clamp_to(hi_r, window.row0, last_row);
      const int c0 = clamp_to(lo_c, window.col0, last_col), c1 = clamp_to(hi_c, window.col0, last_col);
      for (int r = r0; r <= r1; ++r)
        for (int c = c0; c <= c1; ++c) {
          double sum = 0;
          for (int a = 0; a < sub_rays_; ++a)
            for (int b = 0; b < sub_rays_; ++b) {
              const Eigen::Vector3d pixel =
                  view.pixel_centre_mm(r - 0.5 + (a + 0.5) * sub, c - 0.5 + (b + 0.5) * sub);
              const Eigen::Vector3d direction = (pixel - view.source_mm).normalized();
              // Distance from the centre to the ray; the chord is 2 sqrt(R^2 - d^2).
              const double along = to_centre.dot(direction);
              const double d2 = to_centre.squaredNorm() - along * along;
              const double h2 = m.radius_mm * m.radius_mm - d2;
              if (h2 > 0) sum += 2.0 * std::sqrt(h2);
            }
          const double add = m.mu_per_mm * sum * sub * sub;
          // A pixel the inner renderer masked stays 0 and masked (drr_renderer.hpp).
          if (add > 0 && (extras->valid.empty() || extras->valid.at(r - window.row0, c - window.col0) != 0)) {
            float& v = out.at(r - window.row0, c - window.col0);
            v = static_cast<float>(v + add);
          }
        }
    }
    return {};
  }

 private:
  std::shared_ptr<const tracking::DrrRenderer> inner_;
  std::vector<SphereMarker> markers_;
  int sub_rays_;
};

}  // namespace

Result<std::shared_ptr<const tracking::DrrRenderer>> with_sphere_markers(
    std::shared_ptr<const tracking::DrrRenderer> inner, std::vector<SphereMarker> markers, int sub_rays) {
  if (!inner) return invalid_argument("sphere markers: no renderer to add them to");
  if (sub_rays < 1 || sub_rays > 8) return invalid_argument("sphere markers: sub-rays must be 1 to 8");
  for (const SphereMarker& m : markers) {
    if (!m.centre_ct_mm.allFinite()) return invalid_argument("sphere markers: a centre is not finite");
    if (!(m.radius_mm > 0 && m.radius_mm <= 1000))
      return invalid_argument("sphere markers: a radius must be in (0, 1000] mm");
    if (!(m.mu_per_mm >= 0 && m.mu_per_mm <= 100))
      return invalid_argument("sphere markers: mu must be in [0, 100] per mm");
  }
  return std::shared_ptr<const tracking::DrrRenderer>(
      std::make_shared<SphereMarkerRenderer>(std::move(inner), std::move(markers), sub_rays));
}

}  // namespace lftrack::sim
