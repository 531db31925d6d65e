#include "lftrack/host/scene_verdict.hpp"

#include <cstdio>

namespace lftrack::host {

Result<VerdictLimits> verdict_limits(const Scene& scene, const std::string& measure) {
  auto e = similarity_expectation(measure);
  if (!e.ok()) return e.status();
  VerdictLimits limits;
  limits.measure = e->measure;
  limits.no_information_similarity = e->no_information;
  limits.min_similarity = e->min_similarity;
  if (scene.min_similarity_given && measure == scene.registration.similarity)
    limits.min_similarity = scene.safety.min_similarity;
  limits.envelope = scene.envelope;
  return limits;
}

Eigen::Vector3d central_ray_direction_room(const Scene& scene, int index) {
  const tracking::XrayView& view = scene.detectors[static_cast<std::size_t>(index)].view;
  return (view.detector_centre_mm() - view.source_mm).normalized();
}

std::optional<Eigen::Vector3d> unobservable_direction_room(const Scene& scene) {
  if (scene.detectors.size() != 1) return std::nullopt;
  return central_ray_direction_room(scene, 0);
}

Status check_views_observable(const Scene& scene) {
  const auto direction = unobservable_direction_room(scene);
  if (!direction || scene.registration.single_view) return {};
  char d[96];
  std::snprintf(d, sizeof d, "(%.3f, %.3f, %.3f)", direction->x(), direction->y(), direction->z());
  return failed_precondition(scene.source + ": one detector ('" + scene.detectors[0].view.name +
                             "'): a single view cannot see depth along its central ray " + d +
                             " (room frame); say `tracking: {single_view: true}` in the scene to register anyway");
}

}  // namespace lftrack::host
