#pragma once
// Implanted fiducials written into a volume (a scene's `fiducials: {insert: true}`): steel
// spheres in the planning CT at its top HU value, and in the room's attenuation at steel's.

#include <Eigen/Core>
#include <vector>

#include "lftrack/tracking/volume.hpp"

namespace lftrack::phantom {

// Steel markers (spheres, partial volume from 4^3 sub-samples per voxel) written into a volume:
// marker_value replaces the voxel's value in proportion to the sphere's share of it. Centres in
// the volume's CT frame (mm); a sphere partly or wholly outside the volume writes what is inside.
template <class Unit>
void insert_markers(tracking::ScalarVolume<Unit>* volume, const std::vector<Eigen::Vector3d>& centres_ct_mm,
                    double radius_mm, float marker_value);

// Attenuation of stainless steel at about 70 keV (1/mm); a CT shows the same marker clipped at
// its top HU value (kMarkerHu).
inline constexpr float kSteelMuPerMm = 0.7f;
inline constexpr float kMarkerHu = 3071.f;

}  // namespace lftrack::phantom
