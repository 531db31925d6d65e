#include "lftrack/session/scene_exposure.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/drr_renderer.hpp"

namespace lftrack::session {

namespace {

// Every fourth pixel of a ROI window is enough for its mean.
constexpr int kSampleStride = 4;

// The mean of exp(-p) over `window` of `view` at `pose`: the ideal primary's transmission.
Result<double> mean_transmission(const tracking::DrrRenderer& exact, const tracking::Pose& pose,
                                 const tracking::XrayView& view, const tracking::PixelWindow& window) {
  const int rows = std::max(1, window.rows / kSampleStride), cols = std::max(1, window.cols / kSampleStride);
  const tracking::XrayView coarse = view.resampled(window.row0, window.col0, window.rows, window.cols, rows, cols);
  tracking::Image<float> p(rows, cols);
  LFTRACK_RETURN_IF_ERROR(exact.render(pose, coarse, tracking::PixelWindow::full(rows, cols), p.view()));
  double sum = 0;
  for (float v : p.pixels()) sum += std::exp(-double(std::max(0.f, v)));
  return sum / double(p.pixels().size());
}

}  // namespace

Result<SimExposure> scene_exposure(const PreparedScene& p) {
  const SimFrameSpec& sim = p.scene.sim;
  SimExposure e;
  e.photons_per_pixel = sim.photons_per_pixel;
  e.open_field_fraction = kReferenceOpenFieldFraction;
  if (sim.exposure != "aec" || p.scene.detectors.empty()) return e;
  auto exact = tracking::make_renderer("siddon", p.world_mu);
  if (!exact.ok()) return exact.status();
  std::vector<double> transmission;
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    auto t = mean_transmission(**exact, p.nominal_T_room_from_ct, p.scene.detectors[i].view, p.roi_windows[i]);
    if (!t.ok()) return t.status().with_context("sim.exposure: view " + p.scene.detectors[i].view.name);
    transmission.push_back(*t);
  }
  const double darkest = *std::min_element(transmission.begin(), transmission.end());
  // The open field's level (as a fraction of full scale) at which the darkest ROI reads aec_level,
  // within the synthesizers' photon ceiling (a ROI that nothing reaches then reads less: the
  // description says how much).
  const double ceiling = kReferenceOpenFieldFraction * sim_spec::kMaxPhotonsPerPixel / sim.photons_per_pixel;
  const double open_field = darkest > 0 ? sim.aec_level / darkest : ceiling;
  e.open_field_fraction = std::clamp(open_field, 1e-3, ceiling);
  e.photons_per_pixel = sim.photons_per_pixel * e.open_field_fraction / kReferenceOpenFieldFraction;
  for (double t : transmission) e.roi_mean_of_full_scale.push_back(t * e.open_field_fraction);
  return e;
}

std::string describe_exposure(const PreparedScene& p) {
  const SimExposure& e = p.exposure;
  if (e.roi_mean_of_full_scale.empty())
    return fmt::format("fixed exposure: {:.3g} photons per pixel in the open field", e.photons_per_pixel);
  std::string means;
  for (std::size_t i = 0; i < e.roi_mean_of_full_scale.size() && i < p.scene.detectors.size(); ++i)
    means += fmt::format("{}{:.1f} % ({})", i == 0 ? "" : ", ", 100 * e.roi_mean_of_full_scale[i],
                         p.scene.detectors[i].view.name);
  return fmt::format("AEC: {:.3g} photons per pixel in the open field (x{:.3g} the detector's reference); ROI means {} "
                     "of full scale",
                     e.photons_per_pixel, e.photons_per_pixel / p.scene.sim.photons_per_pixel, means);
}

}  // namespace lftrack::session
