#include "lftrack/session/scene_verdict.hpp"

#include "lftrack/session/commissioning_file.hpp"

#include <algorithm>

#include <cstdio>

namespace lftrack::session {

using loop::judges_view_shift;
using loop::similarity_expectation;
using loop::VerdictLimits;

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
  limits.envelope_edge_mm = scene.verdict_checks.envelope_edge_mm;
  limits.envelope_edge_deg = scene.verdict_checks.envelope_edge_deg;
  // The view check compares views: with one there is nothing to compare.
  if (scene.verdict_checks.max_view_shift_mm > 0 && scene.detectors.size() >= 2)
    limits.max_view_shift_mm = scene.verdict_checks.max_view_shift_mm;
  return limits;
}

Result<VerdictLimits> scene_verdict_limits(const PreparedScene& p, const std::string& measure,
                                           std::string* floors_from) {
  auto limits = verdict_limits(p.scene, measure);
  if (!limits.ok()) return limits.status();
  const std::string& file = p.scene.commissioning_file;
  if (file.empty()) {
    if (floors_from) *floors_from = "the measure's defaults (the scene is not commissioned: lftrack commission)";
    return limits;
  }
  auto record = read_commissioning_file(file);
  if (!record.ok()) {
    const bool there = record.status().code() != StatusCode::kNotFound;
    const std::string how = " (safety.commissioning; make it with: lftrack commission --scene " + p.scene.source +
                            (there ? " --replace" : "") + ")";
    return Status(record.status().code(), record.status().message() + how);
  }
  LFTRACK_RETURN_IF_ERROR(check_commissioning_current(p, *record, file));
  // The two floors were chosen together: with another measure (register --similarity, a study's
  // method) the commissioned check floor alone may be lower than the default, so the higher holds.
  // The view check's commissioned limit, never above the scene's own (the fingerprint holds it).
  if (judges_view_shift(*limits) && record->max_view_shift_mm > 0)
    limits->max_view_shift_mm = std::min(limits->max_view_shift_mm, record->max_view_shift_mm);
  if (measure == record->measure) {
    limits->min_similarity = record->min_similarity;
    limits->min_check_ncc = record->min_check_ncc;
  } else {
    limits->min_check_ncc = std::max(limits->min_check_ncc, record->min_check_ncc);
  }
  if (floors_from)
    *floors_from = file + (measure == record->measure
                               ? ""
                               : " (commissioned for " + record->measure + ": " + measure +
                                     " at its default floor, the check NCC at the higher of the two)");
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

}  // namespace lftrack::session
