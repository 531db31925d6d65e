#pragma once
// What a scene expects of a registration (registration_verdict.hpp judges one against it): the
// verdict's limits resolved from the scene, and whether the scene's views can observe every
// direction.

#include <Eigen/Core>
#include <optional>
#include <string>

#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::session {

// The scene's limits for registrations with `measure`: the floor is safety.min_similarity when
// the scene names it and `measure` is the scene's own tracking.similarity (the floor is in that
// measure's units), else the measure's default; the envelope is the scene's.
Result<loop::VerdictLimits> verdict_limits(const Scene& scene, const std::string& measure);

// The limits the loop and `lftrack register` judge with: verdict_limits(), and where the scene
// names a commissioning file (safety.commissioning) its floors: min_check_ncc always, and
// min_similarity where `measure` is the one commissioned. A named file that is missing, malformed
// or measured on another CT, room, registration or imaging (commissioning_file.hpp) is an error
// that says how to commission the scene again. `floors_from` (when given) receives where the
// floors came from, for people: the file, or "the measure's defaults (not commissioned)".
Result<loop::VerdictLimits> scene_verdict_limits(const PreparedScene& scene, const std::string& measure,
                                                 std::string* floors_from = nullptr);

// Depth along a view's central ray is unobservable from that view alone. The unit vector of
// detector `index`'s central ray (from the source to the detector's centre), room frame.
Eigen::Vector3d central_ray_direction_room(const Scene& scene, int index);
// With one detector: the direction a registration cannot see (its central ray), room frame;
// nothing with two or more.
std::optional<Eigen::Vector3d> unobservable_direction_room(const Scene& scene);
// Refuses a scene whose views cannot observe every direction (one detector) unless it says
// `tracking.single_view: true`; then (and with two or more detectors) OK.
Status check_views_observable(const Scene& scene);

}  // namespace lftrack::session
