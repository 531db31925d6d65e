// `lftrack info`: the scene's volume, views and ROI windows, for a person to check a set-up.

#include <cstdio>

#include "cli_commands.hpp"
#include "lftrack/session/patient_setup.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::describe_frames;
using session::PreparedScene;
using session::printable;

Command add_info_command(CLI::App* parent) {
  auto* app = parent->add_subcommand(
      "info",
      "Print the scene's CT volume and X-ray geometry. A CT given with --ct to a scene that names no "
      "roi.centre_mm (e.g. the built-in one) has its ROI, and its registration origin unless the scene names "
      "registration_origin_mm, at the volume centre; the output says so");
  auto options = std::make_shared<SceneOptions>();
  add_scene_options(app, options.get());
  return [options]() -> Status {
    tracking::ThreadPool pool(options->threads);
    auto prepared = load_prepared_scene(*options, &pool);
    if (!prepared.ok()) return prepared.status();
    const PreparedScene& p = *prepared;
    const auto& g = p.ct->geometry;
    auto v3 = [](const Eigen::Vector3d& v) {
      char b[96];
      std::snprintf(b, sizeof b, "(%.2f, %.2f, %.2f)", v.x(), v.y(), v.z());
      return std::string(b);
    };
    float lo = 1e30f, hi = -1e30f;
    for (float v : p.ct->values) {
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
    std::printf("scene           %s (%s)\n", p.scene.source.c_str(), p.scene.name.c_str());
    std::printf("ct              %s\n", p.scene.ct.path.c_str());
    std::printf("  voxels        %d x %d x %d\n", g.size.x(), g.size.y(), g.size.z());
    std::printf("  spacing mm    %s\n", v3(g.spacing_mm).c_str());
    std::printf("  origin mm     %s (CT frame, LPS)\n", v3(g.origin_mm).c_str());
    std::printf("  axes i j k    %s %s %s\n", v3(g.direction.col(0)).c_str(), v3(g.direction.col(1)).c_str(),
                v3(g.direction.col(2)).c_str());
    std::printf("  extent mm     %s\n", v3(g.extent_mm()).c_str());
    std::printf("  HU range      %.0f .. %.0f\n", double(lo), double(hi));
    std::printf("  mu_water      %.4f /mm\n", p.scene.ct.mu_water_per_mm);
    const char* volume_centre = ": the volume centre, as no scene names roi.centre_mm";
    std::printf("roi             centre %s mm, size %s mm (CT frame)%s\n", v3(p.roi_centre_ct_mm).c_str(),
                v3(p.scene.roi.size_mm).c_str(), p.roi_centre_is_volume_centre ? volume_centre : "");
    if (const auto& mask = p.scene.roi.mask) {
      std::printf("roi mask        target '%s' of %s, %g mm around it; pixels looked at per view:",
                  printable(mask->target).c_str(), mask->rtstruct.c_str(), mask->margin_mm);
      for (std::size_t v = 0; v < p.roi_masks.size(); ++v) {
        std::int64_t n = 0;
        for (unsigned char b : p.roi_masks[v].pixels()) n += b != 0;
        std::printf(" %s %lld of %zu", p.scene.detectors[v].view.name.c_str(), static_cast<long long>(n),
                    p.roi_masks[v].pixels().size());
      }
      std::printf("\n");
    }
    const bool origin_is_volume_centre = p.roi_centre_is_volume_centre && !p.scene.registration_origin_ct_mm;
    std::printf("registration    origin %s mm (CT) = %s mm (room)%s\n", v3(p.registration_origin_ct_mm).c_str(),
                v3(p.registration_origin_room_mm()).c_str(),
                origin_is_volume_centre ? ": the volume centre, as no scene names it (registration_origin_mm)" : "");
    std::printf("envelope        +-%.1f mm, +-%.1f deg\n", p.scene.envelope.translation_mm,
                p.scene.envelope.rotation_deg);
    for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
      const auto& d = p.scene.detectors[i];
      const auto& v = d.view;
      const auto& w = p.roi_windows[i];
      std::printf("view %-10s %d x %d pixels of %.3f x %.3f mm, %d-bit, frames from %s\n", v.name.c_str(),
                  v.rows, v.cols, v.pitch_row_mm, v.pitch_col_mm, d.bits, describe_frames(d.frames).c_str());
      std::printf("  source mm     %s (room)\n", v3(v.source_mm).c_str());
      std::printf("  pixel(0,0) mm %s, col axis %s, row axis %s\n", v3(v.pixel00_mm).c_str(),
                  v3(v.col_axis).c_str(), v3(v.row_axis).c_str());
      std::printf("  SID mm        %.1f\n", v.source_to_detector_mm());
      std::printf("  ROI window    rows %d..%d, cols %d..%d\n", w.row0, w.row0 + w.rows - 1, w.col0,
                  w.col0 + w.cols - 1);
    }
    return {};
  };
}

}  // namespace lftrack::cli
