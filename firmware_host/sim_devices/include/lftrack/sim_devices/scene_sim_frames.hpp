#pragma once
// A scene's frames as the simulator makes them: the renderer of its frames (sim.renderer), its
// detector model, the pixels it exposes, and synthetic raw frames at a gold pose (the studies',
// the commissioning's and the tests' frames).

#include <cstdint>
#include <filesystem>
#include <memory>
#include <vector>

#include "lftrack/session/scene.hpp"
#include "lftrack/sim/synthetic_frames.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/image.hpp"

namespace lftrack::sim_devices {

// What renders the simulated loop's frames (sim.renderer): Siddon through the world anatomy
// (markers included), or a separate light field of sim.light_field's resolution built from it and
// cached in <light_field_dir>/sim-frames.
Result<std::shared_ptr<const tracking::DrrRenderer>> make_sim_frame_renderer(
    const session::PreparedScene& scene, const std::filesystem::path& light_field_dir,
    tracking::ThreadPool* pool);

// The detector model of the scene's sim section.
sim::DetectorModel scene_detector_model(const session::PreparedScene& scene);

// The pixels the simulator exposes on detector `detector`: its ROI window grown by `margin_px`
// (clipped to the detector).
tracking::PixelWindow sim_frame_window(const session::PreparedScene& scene, int detector, int margin_px);

// The margin the simulated detectors expose around each ROI window: none for light-field frames
// (a field covers the ROI only), 16 pixels for Siddon's.
int sim_frame_margin_px(const session::PreparedScene& scene);

// The folder of the simulator's frame fields: <light_field_dir>/sim-frames (`light_field_dir`
// empty: the scene's default folder).
std::filesystem::path sim_frame_fields_dir(const session::PreparedScene& scene,
                                           const std::filesystem::path& light_field_dir);

// Synthetic raw frames at `gold`, rendered exactly (Siddon on the scene's world anatomy, markers
// included) over each ROI window grown by a margin; the rest of each detector is unexposed.
Result<std::vector<tracking::Image<std::uint16_t>>> synthesize_scene_frames(
    const session::PreparedScene& scene, const tracking::DrrRenderer& exact,
    const tracking::Pose& gold_T_room_from_ct, std::uint64_t seed);

}  // namespace lftrack::sim_devices
