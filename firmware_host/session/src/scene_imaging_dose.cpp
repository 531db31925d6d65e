#include "lftrack/session/scene_imaging_dose.hpp"

#include <fmt/format.h>

#include <algorithm>

namespace lftrack::session {

double skin_entrance_dose_mGy(const ImagingTechniqueSpec& technique, double source_to_skin_mm) {
  const double output = kOutputAt100kV * (technique.kvp / 100) * (technique.kvp / 100);
  const double distance_m =
      std::max(source_to_skin_mm, 100.0) / 1000;  // a source nearer than 10 cm is no geometry
  return output * technique.mas * kBackscatter / (distance_m * distance_m);
}

double imaging_dose_per_pair_mGy(const PreparedScene& scene) {
  const Eigen::Vector3d origin = scene.registration_origin_room_mm();
  double dose = 0;
  for (const DetectorSpec& d : scene.scene.detectors) {
    const double to_origin = (origin - d.view.source_mm).norm();
    dose += skin_entrance_dose_mGy(scene.scene.technique, to_origin - kSkinBeforeIsocentreMm);
  }
  return dose;
}

std::string describe_imaging_dose(const PreparedScene& scene) {
  return fmt::format(
      "{:g} kV, {:g} mAs per view: {:.3g} mGy skin entrance per pair (a stated model: docs/scenes.md)",
      scene.scene.technique.kvp, scene.scene.technique.mas, imaging_dose_per_pair_mGy(scene));
}

}  // namespace lftrack::session
