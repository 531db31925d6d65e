#include "lftrack/tracking/octree_volume.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <string>

namespace lftrack::tracking {
namespace {

// Smallest depth with 2^depth >= every axis size.
int depth_for(const Eigen::Vector3i& size) {
  int depth = 0;
  while ((1 << depth) < size.maxCoeff()) ++depth;
  return depth;
}

// Node counts per axis at level l: ceil(size / 2^l).
Eigen::Vector3i dims_at(const Eigen::Vector3i& size, int l) {
  const int n = 1 << l;
  return Eigen::Vector3i((size.x() + n - 1) / n, (size.y() + n - 1) / n, (size.z() + n - 1) / n);
}

// Walks the ordered leaf list depth first, calling leaf(slot, level, x, y, z, leaf_index) for
// each leaf with its node coordinates at its level, and inner(slot, level, x, y, z) before an
// inner node's children; inner returns a slot number s, and child c (i bit + 2 j bit + 4 k bit)
// is then given slot s + c (the root has slot 0). Fails if the list does not cover the geometry
// exactly.
template <class Leaf, class Inner>
Status walk_leaves(const Eigen::Vector3i& size, int depth, const std::vector<std::uint8_t>& levels,
                   const Leaf& leaf, const Inner& inner) {
  std::size_t cursor = 0;
  Status status;
  auto visit = [&](auto&& self, std::size_t slot, int l, int x, int y, int z) -> bool {
    if (cursor >= levels.size()) {
      status = corrupt_data("octree: the leaf list ends before the volume is covered (" +
                            std::to_string(cursor) + " leaves)");
      return false;
    }
    const int level = levels[cursor];
    if (level == l) {
      leaf(slot, l, x, y, z, cursor++);
      return true;
    }
    if (level > l || l == 0) {
      status = corrupt_data("octree: leaf " + std::to_string(cursor) + " has level " + std::to_string(level) +
                            " inside a node of level " + std::to_string(l));
      return false;
    }
    const std::size_t first_child = inner(slot, l, x, y, z);
    const Eigen::Vector3i child_dims = dims_at(size, l - 1);
    for (int c = 0; c < 8; ++c) {
      const int cx = 2 * x + (c & 1), cy = 2 * y + ((c >> 1) & 1), cz = 2 * z + ((c >> 2) & 1);
      if (cx >= child_dims.x() || cy >= child_dims.y() || cz >= child_dims.z()) continue;
      if (!self(self, first_child + std::size_t(c), l - 1, cx, cy, cz)) return false;
    }
    return true;
  };
  if (!visit(visit, std::size_t{0}, depth, 0, 0, 0)) return status;
  if (cursor != levels.size()) {
    return corrupt_data("octree: " + std::to_string(levels.size() - cursor) +
                        " leaves left over after the volume is covered");
  }
  return {};
}

}  // namespace

Result<OctreeVolume> OctreeVolume::build(const MuVolume& volume, double pivot) {
  if (auto s = check_attenuation_volume(volume); !s.ok()) return s.with_context("octree");
  if (!(pivot >= 0.0 && pivot <= 1.0)) return out_of_range("octree: pivot must be in [0, 1]");
  float vmin = std::numeric_limits<float>::infinity(), vmax = -vmin;
  for (float v : volume.values) {
    vmin = std::min(vmin, v);
    vmax = std::max(vmax, v);
  }
  OctreeVolume tree;
  tree.geometry_ = volume.geometry;
  tree.pivot_ = pivot;
  tree.threshold_per_mm_ = pivot * (double(vmax) - double(vmin));
  tree.depth_ = depth_for(volume.geometry.size);
  const Eigen::Vector3i size = volume.geometry.size;

  // Min and max per node, level by level (level 0 is the volume itself).
  struct Level {
    Eigen::Vector3i dims;
    std::vector<float> lo, hi;
    std::size_t index(int x, int y, int z) const {
      return std::size_t(x) +
             std::size_t(dims.x()) * (std::size_t(y) + std::size_t(dims.y()) * std::size_t(z));
    }
  };
  std::vector<Level> levels(std::size_t(tree.depth_) + 1);
  levels[0].dims = size;
  for (int l = 1; l <= tree.depth_; ++l) {
    const Level& below = levels[std::size_t(l) - 1];
    Level& level = levels[std::size_t(l)];
    level.dims = dims_at(size, l);
    const std::size_t count = std::size_t(level.dims.x()) * level.dims.y() * level.dims.z();
    level.lo.assign(count, std::numeric_limits<float>::infinity());
    level.hi.assign(count, -std::numeric_limits<float>::infinity());
    for (int z = 0; z < below.dims.z(); ++z)
      for (int y = 0; y < below.dims.y(); ++y)
        for (int x = 0; x < below.dims.x(); ++x) {
          const std::size_t from = below.index(x, y, z);
          const float lo = l == 1 ? volume.values[from] : below.lo[from];
          const float hi = l == 1 ? volume.values[from] : below.hi[from];
          const std::size_t to = level.index(x / 2, y / 2, z / 2);
          level.lo[to] = std::min(level.lo[to], lo);
          level.hi[to] = std::max(level.hi[to], hi);
        }
  }
  const float threshold = static_cast<float>(tree.threshold_per_mm_);
  auto emit = [&](auto&& self, int l, int x, int y, int z) -> void {
    const Level& level = levels[std::size_t(l)];
    const std::size_t at = level.index(x, y, z);
    const float lo = l == 0 ? volume.values[at] : level.lo[at];
    const float hi = l == 0 ? volume.values[at] : level.hi[at];
    if (l == 0 || hi - lo <= threshold) {
      tree.leaf_levels_.push_back(static_cast<std::uint8_t>(l));
      tree.leaf_values_.push_back(lo == hi ? lo : 0.5f * (lo + hi));
      return;
    }
    const Eigen::Vector3i& child_dims = levels[std::size_t(l) - 1].dims;
    for (int c = 0; c < 8; ++c) {
      const int cx = 2 * x + (c & 1), cy = 2 * y + ((c >> 1) & 1), cz = 2 * z + ((c >> 2) & 1);
      if (cx < child_dims.x() && cy < child_dims.y() && cz < child_dims.z()) self(self, l - 1, cx, cy, cz);
    }
  };
  emit(emit, tree.depth_, 0, 0, 0);
  if (tree.leaf_count() > kMaxLeaves) return out_of_range("octree: more than 2^30 leaves");
  return tree;
}

Result<OctreeVolume> OctreeVolume::from_leaves(const VolumeGeometry& geometry,
                                               std::vector<std::uint8_t> leaf_levels,
                                               std::vector<float> leaf_values, double pivot,
                                               double threshold_per_mm) {
  LFTRACK_RETURN_IF_ERROR(geometry.validate());
  if (leaf_levels.size() != leaf_values.size())
    return invalid_argument("octree: " + std::to_string(leaf_levels.size()) + " leaf sizes but " +
                            std::to_string(leaf_values.size()) + " values");
  if (leaf_values.size() > kMaxLeaves) return out_of_range("octree: more than 2^30 leaves");
  for (float v : leaf_values)
    if (!std::isfinite(v)) return invalid_argument("octree: a leaf value is not finite");
  OctreeVolume tree;
  tree.geometry_ = geometry;
  tree.depth_ = depth_for(geometry.size);
  tree.pivot_ = pivot;
  tree.threshold_per_mm_ = threshold_per_mm;
  LFTRACK_RETURN_IF_ERROR(walk_leaves(
      geometry.size, tree.depth_, leaf_levels, [](std::size_t, int, int, int, int, std::size_t) {},
      [](std::size_t, int, int, int, int) { return std::size_t{0}; }));
  tree.leaf_levels_ = std::move(leaf_levels);
  tree.leaf_values_ = std::move(leaf_values);
  return tree;
}

double OctreeVolume::cell_reduction() const {
  const double voxels = double(geometry_.voxel_count());
  return voxels > 0 ? 1.0 - double(leaf_count()) / voxels : 0.0;
}

MuVolume OctreeVolume::decompress() const {
  MuVolume out;
  out.geometry = geometry_;
  out.values.assign(std::size_t(geometry_.voxel_count()), 0.0f);
  const Eigen::Vector3i size = geometry_.size;
  const Status s = walk_leaves(
      size, depth_, leaf_levels_,
      [&](std::size_t, int l, int x, int y, int z, std::size_t n) {
        const int i0 = x << l, j0 = y << l, k0 = z << l;
        const int i1 = std::min(i0 + (1 << l), size.x()), j1 = std::min(j0 + (1 << l), size.y()),
                  k1 = std::min(k0 + (1 << l), size.z());
        for (int k = k0; k < k1; ++k)
          for (int j = j0; j < j1; ++j)
            std::fill(&out.at(i0, j, k), &out.at(i0, j, k) + (i1 - i0), leaf_values_[n]);
      },
      [](std::size_t, int, int, int, int) { return std::size_t{0}; });
  (void)s;  // the list was checked when the tree was made
  return out;
}

OctreeNodes::OctreeNodes(const OctreeVolume& octree) : depth_(octree.depth()) {
  // Value 0 stands for the children outside the volume; leaf values follow.
  values_.reserve(octree.leaf_count() + 1);
  values_.push_back(0.0f);
  values_.insert(values_.end(), octree.leaf_values().begin(), octree.leaf_values().end());
  nodes_.reserve(octree.leaf_count() + octree.leaf_count() / 6 + 8);
  nodes_.push_back(kLeafBit);  // the root's slot
  const Status s = walk_leaves(
      octree.geometry().size, depth_, octree.leaf_levels(),
      [&](std::size_t slot, int, int, int, int, std::size_t n) {
        nodes_[slot] = kLeafBit | std::uint32_t(n + 1);
      },
      [&](std::size_t slot, int, int, int, int) {
        const std::size_t first = nodes_.size();
        nodes_.resize(first + 8, kLeafBit);  // children outside the volume keep value 0
        nodes_[slot] = std::uint32_t(first);
        return first;
      });
  (void)s;  // the list was checked when the tree was made
}

double octree_line_integral(const OctreeNodes& tree, const VolumeGeometry& g,
                            const Eigen::Vector3d& from_grid_mm, const Eigen::Vector3d& to_grid_mm) {
  if (!from_grid_mm.allFinite() || !to_grid_mm.allFinite()) return 0.0;
  // Cell coordinates: voxel i spans [i, i + 1) on each axis (computed as GridRayCaster does, so
  // a ray along a shared face takes the same side).
  const Eigen::Vector3d lower = -0.5 * g.spacing_mm;
  const Eigen::Vector3d q0 = (from_grid_mm - lower).cwiseQuotient(g.spacing_mm);
  const Eigen::Vector3d dq = (to_grid_mm - from_grid_mm).cwiseQuotient(g.spacing_mm);
  const int n[3] = {g.size.x(), g.size.y(), g.size.z()};
  // Clip the parameter a in [0, 1] to the box [0, n) (half-open, as GridRayCaster::clip).
  double a = 0.0, a_end = 1.0;
  for (int ax = 0; ax < 3; ++ax) {
    if (dq[ax] == 0.0) {
      if (q0[ax] < 0.0 || q0[ax] >= n[ax]) return 0.0;
      continue;
    }
    const double t0 = -q0[ax] / dq[ax], t1 = (n[ax] - q0[ax]) / dq[ax];
    a = std::max(a, std::min(t0, t1));
    a_end = std::min(a_end, std::max(t0, t1));
  }
  if (!(a_end > a)) return 0.0;
  int cell[3];
  for (int ax = 0; ax < 3; ++ax) {
    const double q = q0[ax] + a * dq[ax];
    cell[ax] = std::clamp(static_cast<int>(std::floor(q)), 0, n[ax] - 1);
  }
  // Per axis: the parameter step per cell (infinite along axes the ray does not move on).
  double inv_dq[3];
  for (int ax = 0; ax < 3; ++ax) inv_dq[ax] = dq[ax] != 0.0 ? 1.0 / dq[ax] : 0.0;
  // path[l]: the node word at level l on the way to the current leaf, so that the next leaf is
  // found from the two cells' lowest common ancestor rather than from the root.
  const std::uint32_t* words = tree.nodes().data();
  const float* values = tree.values().data();
  std::uint32_t path[33];
  int from_level = tree.depth();
  path[from_level] = words[0];
  double sum = 0.0;
  for (;;) {
    int level = from_level;
    std::uint32_t word = path[level];
    while (!(word & OctreeNodes::kLeafBit)) {
      --level;
      const std::uint32_t child =
          ((cell[0] >> level) & 1) | (((cell[1] >> level) & 1) << 1) | (((cell[2] >> level) & 1) << 2);
      word = words[word + child];
      path[level] = word;
    }
    const float mu = values[word & ~OctreeNodes::kLeafBit];
    // The leaf's box, clipped to the volume, and where the ray leaves it.
    int lo[3], hi[3];
    double face[3];
    double exit = a_end;
    for (int ax = 0; ax < 3; ++ax) {
      lo[ax] = (cell[ax] >> level) << level;
      hi[ax] = std::min(lo[ax] + (1 << level), n[ax]);
      face[ax] = dq[ax] != 0.0 ? ((dq[ax] > 0 ? hi[ax] : lo[ax]) - q0[ax]) * inv_dq[ax]
                               : std::numeric_limits<double>::infinity();
      exit = std::min(exit, face[ax]);
    }
    exit = std::max(exit, a);  // rounding never steps back
    sum += double(mu) * (exit - a);
    if (exit >= a_end) break;
    // Step into the neighbouring leaf: along every axis whose face is reached the cell moves
    // past it (strict progress, so the walk ends); along the others it stays inside the box.
    bool left_volume = false;
    int changed = 0;
    for (int ax = 0; ax < 3; ++ax) {
      const int before = cell[ax];
      if (face[ax] <= exit) {
        cell[ax] = dq[ax] > 0 ? hi[ax] : lo[ax] - 1;
        left_volume |= cell[ax] < 0 || cell[ax] >= n[ax];
      } else {
        cell[ax] = std::clamp(static_cast<int>(std::floor(q0[ax] + exit * dq[ax])), lo[ax], hi[ax] - 1);
      }
      changed |= before ^ cell[ax];
    }
    a = exit;
    if (left_volume) break;
    // The lowest common ancestor of the old and the new cell: the first level whose node index
    // agrees on every axis.
    from_level = std::max(level, static_cast<int>(std::bit_width(static_cast<unsigned>(changed))));
  }
  return sum * (to_grid_mm - from_grid_mm).norm();
}

}  // namespace lftrack::tracking
