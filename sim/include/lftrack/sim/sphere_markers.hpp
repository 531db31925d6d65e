#pragma once
// Metal markers seen as the spheres they are. A CT voxel holds one value over its whole extent, so
// a 2 mm sphere written into 3 mm slices projects as a slab centred on its slice, up to half a
// slice from the real centre; a fiducial located on such frames is off by that much. This
// renderer adds each sphere's exact line integral (mu x chord length, averaged over sub-rays
// across the pixel) to what another renderer gives, so simulated frames show the marker where it
// is.

#include <Eigen/Core>
#include <memory>
#include <vector>

#include "lftrack/tracking/drr_renderer.hpp"

namespace lftrack::sim {

struct SphereMarker {
  Eigen::Vector3d centre_ct_mm = Eigen::Vector3d::Zero();
  double radius_mm = 1;
  double mu_per_mm = 0;  // added to what the volume holds there
};

// render() = inner's render() + sum over spheres of mu * chord(ray, sphere), with `sub_rays` x
// `sub_rays` rays per pixel (1 to 8). The inner renderer's validity mask is kept. Fails at
// creation for a null inner renderer, a non-finite centre, a radius outside (0, 1000] mm or a mu
// outside [0, 100] per mm.
Result<std::shared_ptr<const tracking::DrrRenderer>> with_sphere_markers(
    std::shared_ptr<const tracking::DrrRenderer> inner, std::vector<SphereMarker> markers, int sub_rays = 4);

}  // namespace lftrack::sim
