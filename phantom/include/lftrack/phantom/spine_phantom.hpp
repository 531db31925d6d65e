#pragma once
// A procedural lumbar-spine CT generated in memory from a seed: the built-in default scene's
// anatomy, so lftrack runs with no data files.
//
// Contents (HU): air -1000 around the body; a carbon-fibre couch; skin and subcutaneous fat
// (-100); soft tissue (40) with psoas muscles (55), kidneys (30), aorta (45) and bowel gas
// (-900); vertebral bodies with a cortical shell (about 1100) around textured cancellous bone
// (about 220); discs (90); pedicles, laminae, spinous and transverse processes (cortical mix,
// about 750); the spinal canal (CSF, 15). Edges are anti-aliased over one voxel, and the image
// carries Gaussian noise (sigma 12 HU). The same seed and options give the same volume,
// bit for bit, whatever the thread count.
//
// Frame: CT frame = patient LPS for a head-first supine patient; direction = identity.

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::phantom {

struct SpinePhantomOptions {
  std::uint64_t seed = 1;
  Eigen::Vector3i size{384, 384, 176};           // voxels (i = L, j = P, k = S)
  Eigen::Vector3d spacing_mm{0.9, 0.9, 1.0};     // a clinical spine protocol's grid
  Eigen::Vector3d centre_mm{0.0, 20.0, -350.0};  // volume centre in the CT frame
  double noise_hu = 12.0;                        // Gaussian image noise, standard deviation
};

struct SpinePhantom {
  tracking::CtVolume ct;
  // Centres of the vertebral bodies, CT frame, inferior to superior.
  std::vector<Eigen::Vector3d> vertebral_body_centres_mm;
  // Index of the vertebra the default scene tracks (the middle one).
  int target_vertebra = 0;
};

// Builds the phantom; uses `pool` for the voxel loop when given. Fails only for invalid options
// (a grid too small to hold one vertebra, non-positive spacing).
Result<SpinePhantom> make_spine_phantom(const SpinePhantomOptions& options,
                                        tracking::ThreadPool* pool = nullptr);

// The phantom without its voxels: the CT's geometry (ct.values empty), the vertebral body
// centres and the target, exactly as make_spine_phantom gives them for the same options, for a
// fraction of a millisecond. What a cache of the voxels needs around them (session::phantom_cache).
// Fails as make_spine_phantom does.
Result<SpinePhantom> spine_phantom_layout(const SpinePhantomOptions& options);

}  // namespace lftrack::phantom
