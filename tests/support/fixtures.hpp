#pragma once
// Small shared fixtures for renderer tests: a textured volume, a view of it, and light fields
// built over them (cached per storage mode, since building takes a moment).

#include <memory>

#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/volume.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::test {

// 48 x 40 x 36 voxels: a soft-tissue cylinder with a dense off-centre block and a smooth texture.
std::shared_ptr<const tracking::MuVolume> fixture_volume();
// A box of `size` voxels of `spacing_mm`, every voxel `mu`, origin at voxel (0,0,0) = (0,0,0).
tracking::MuVolume uniform_box(Eigen::Vector3i size, Eigen::Vector3d spacing_mm, float mu);
// An oblique isocentric view of it, 48 x 40 pixels of 1 mm, source 400 mm from the isocentre.
tracking::XrayView fixture_view();
// The light-field plan input for fixture_view(): whole detector, nominal identity pose, origin
// and ROI centre at the isocentre, envelope +-3 mm and +-12 degrees.
tracking::LightFieldPlanInput fixture_plan();
// A 12 x 12 x 64 x 64 field over the fixture in `storage` (VQ: 256 codewords), built once.
std::shared_ptr<const tracking::LightField> fixture_light_field(tracking::LightFieldStorage storage);

}  // namespace lftrack::test
