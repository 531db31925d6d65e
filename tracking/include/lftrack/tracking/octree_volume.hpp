#pragma once
// Octree-compressed attenuation volumes (PAPERS.md, paper 3: Dorgham, Fisher, Laycock).
//
// The volume is split recursively into octants while (max - min) of a node's voxels exceeds the
// threshold T = pivot * (max - min of the whole volume); a node that is not split becomes a leaf
// holding one value. Pivot 0 splits every node that is not exactly uniform, so it is lossless.
//
// Layout: the root is the cube of 2^depth voxels (depth the smallest with 2^depth >= every axis
// size) whose corner is voxel (0,0,0). A node of level l covers voxels [x 2^l, (x+1) 2^l) on
// each axis, clipped to the volume; nodes wholly outside the volume do not exist. Leaves are
// stored as the paper's ordered list of (size, value): depth first, children in the order
// i bit + 2 j bit + 4 k bit, so a leaf's position follows from its place in the list.
//
// A leaf's value is the midrange (min + max) / 2 of its voxels, so every voxel differs from
// its leaf by at most T / 2.

#include <cstdint>
#include <memory>
#include <vector>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::tracking {

class OctreeVolume {
 public:
  // Node indices are 31-bit (OctreeNodes), so a tree holds at most this many leaves.
  static constexpr std::size_t kMaxLeaves = std::size_t{1} << 30;

  // Compresses `volume` at `pivot` in [0, 1]. Fails for an invalid or empty volume, a volume
  // with non-finite values, or a pivot outside [0, 1].
  static Result<OctreeVolume> build(const MuVolume& volume, double pivot);

  // Rebuilds an octree from its parts (as a file would hold them); checks that the list covers
  // the geometry exactly.
  static Result<OctreeVolume> from_leaves(const VolumeGeometry& geometry,
                                          std::vector<std::uint8_t> leaf_levels,
                                          std::vector<float> leaf_values, double pivot = 0,
                                          double threshold_per_mm = 0);

  const VolumeGeometry& geometry() const { return geometry_; }
  double pivot() const { return pivot_; }
  double threshold_per_mm() const { return threshold_per_mm_; }  // T, in mu units (1/mm)
  int depth() const { return depth_; }

  // The ordered list: leaf n has size 2^leaf_levels()[n] voxels per axis (before clipping).
  const std::vector<std::uint8_t>& leaf_levels() const { return leaf_levels_; }
  const std::vector<float>& leaf_values() const { return leaf_values_; }
  std::size_t leaf_count() const { return leaf_values_.size(); }

  // 1 - leaves / voxels: the paper's "compression" (0 for a volume of distinct voxels).
  double cell_reduction() const;
  // Bytes of the ordered list: one byte of size and a float per leaf.
  std::size_t list_bytes() const { return leaf_count() * (sizeof(std::uint8_t) + sizeof(float)); }

  // The volume the octree stands for: every voxel set to its leaf's value.
  MuVolume decompress() const;

 private:
  VolumeGeometry geometry_;
  double pivot_ = 0;
  double threshold_per_mm_ = 0;
  int depth_ = 0;
  std::vector<std::uint8_t> leaf_levels_;
  std::vector<float> leaf_values_;
};

// The octree's nodes laid out for ray traversal: one 32-bit word per node; a leaf word holds
// kLeafBit | index into values(), an inner word the index of its first of eight consecutive
// children. Children outside the volume are leaves of value 0 (never reached by a ray clipped
// to the volume).
class OctreeNodes {
 public:
  static constexpr std::uint32_t kLeafBit = 0x8000'0000u;

  explicit OctreeNodes(const OctreeVolume& octree);

  const std::vector<std::uint32_t>& nodes() const { return nodes_; }
  const std::vector<float>& values() const { return values_; }
  int depth() const { return depth_; }
  std::size_t bytes() const { return nodes_.size() * sizeof(std::uint32_t) + values_.size() * sizeof(float); }

  // The leaf holding voxel (i, j, k), which must lie inside the volume: its value and level.
  float leaf_at(int i, int j, int k, int* level) const {
    std::uint32_t word = nodes_[0];
    int l = depth_;
    while (!(word & kLeafBit)) {
      --l;
      const std::uint32_t child = ((i >> l) & 1) | (((j >> l) & 1) << 1) | (((k >> l) & 1) << 2);
      word = nodes_[word + child];
    }
    *level = l;
    return values_[word & ~kLeafBit];
  }

 private:
  int depth_ = 0;
  std::vector<std::uint32_t> nodes_;
  std::vector<float> values_;
};

// The line integral of mu along the segment [from, to] (grid frame, as GridRayCaster) through the
// octree, one step per leaf crossed: equal to GridRayCaster::siddon on the decompressed volume.
double octree_line_integral(const OctreeNodes& nodes, const VolumeGeometry& geometry,
                            const Eigen::Vector3d& from_grid_mm, const Eigen::Vector3d& to_grid_mm);

}  // namespace lftrack::tracking
