// A scene's frames as the simulator makes them (scene_sim_frames.hpp).

#include "lftrack/sim_devices/scene_sim_frames.hpp"

#include <algorithm>

#include "lftrack/tracking/light_field.hpp"

namespace lftrack::sim_devices {

using session::default_light_field_dir;
using session::load_or_build_light_fields;
using session::PreparedScene;
using tracking::Image;
using tracking::Pose;

int sim_frame_margin_px(const PreparedScene& p) {
  return p.scene.sim.renderer == "lightfield" ? 0 : 16;
}

std::filesystem::path sim_frame_fields_dir(const PreparedScene& p,
                                           const std::filesystem::path& light_field_dir) {
  return (light_field_dir.empty() ? default_light_field_dir(p.scene) : light_field_dir) / "sim-frames";
}

Result<std::shared_ptr<const tracking::DrrRenderer>> make_sim_frame_renderer(
    const PreparedScene& p, const std::filesystem::path& lf_dir, tracking::ThreadPool* pool) {
  tracking::RendererOptions options;
  options.light_field_mips = false;  // whole-detector frames: no coarse pixels to average
  if (p.scene.sim.renderer == "lightfield") {
    auto fields = load_or_build_light_fields(p, *p.world_mu, p.scene.sim.light_field,
                                             sim_frame_fields_dir(p, lf_dir), pool);
    if (!fields.ok()) return fields.status().with_context("the simulator's frame fields");
    options.light_fields = *fields;
  }
  auto renderer = tracking::make_renderer(p.scene.sim.renderer, p.world_mu, options);
  if (!renderer.ok()) return renderer.status();
  return std::shared_ptr<const tracking::DrrRenderer>(std::move(renderer).value());
}

sim::DetectorModel scene_detector_model(const PreparedScene& p) {
  sim::DetectorModel m;
  m.photons_per_pixel = p.exposure.photons_per_pixel;
  m.open_field_fraction = p.exposure.open_field_fraction;
  m.blur_sigma_px = p.scene.sim.detector_blur_px;
  m.bits = p.scene.detectors.empty() ? 12 : p.scene.detectors.front().bits;
  return m;
}

tracking::PixelWindow sim_frame_window(const PreparedScene& p, int detector, int margin_px) {
  const auto& view = p.scene.detectors[std::size_t(detector)].view;
  const tracking::PixelWindow& w = p.roi_windows[std::size_t(detector)];
  tracking::PixelWindow grown{std::max(0, w.row0 - margin_px), std::max(0, w.col0 - margin_px), 0, 0};
  grown.rows = std::min(view.rows, w.row0 + w.rows + margin_px) - grown.row0;
  grown.cols = std::min(view.cols, w.col0 + w.cols + margin_px) - grown.col0;
  return grown;
}

Result<std::vector<Image<std::uint16_t>>> synthesize_scene_frames(const PreparedScene& p,
                                                                  const tracking::DrrRenderer& exact,
                                                                  const Pose& gold, std::uint64_t seed) {
  std::vector<Image<std::uint16_t>> frames;
  const sim::DetectorModel model = scene_detector_model(p);
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    const auto& view = p.scene.detectors[i].view;
    const tracking::PixelWindow grown = sim_frame_window(p, int(i), 16);
    auto frame = sim::synthesize_frame(exact, gold, view, grown, model, seed * 7919 + i);
    if (!frame.ok()) return frame.status().with_context("view " + view.name);
    frames.push_back(std::move(frame).value());
  }
  return frames;
}

}  // namespace lftrack::sim_devices
