// A structure set's target: contours checked, boxed and filled on the CT's grid (issue 53).

#include "lftrack/session/target_contours.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <array>
#include <map>
#include <set>
#include <sstream>

namespace lftrack::session {

namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

std::string contour_name(const std::string& name, std::size_t index) {
  return "target '" + name + "', contour " + std::to_string(index + 1);
}

// Newell's normal: its length is twice the polygon's area.
Vector3d newell_normal(const std::vector<Vector3d>& p) {
  Vector3d n = Vector3d::Zero();
  for (std::size_t i = 0; i < p.size(); ++i) {
    const Vector3d& a = p[i];
    const Vector3d& b = p[(i + 1) % p.size()];
    n += Vector3d((a.y() - b.y()) * (a.z() + b.z()), (a.z() - b.z()) * (a.x() + b.x()), (a.x() - b.x()) * (a.y() + b.y()));
  }
  return n;
}

// The polygon without repeated consecutive points (a closing point equal to the first included).
std::vector<Vector3d> without_repeats(const std::vector<Vector3d>& points) {
  std::vector<Vector3d> out;
  for (const Vector3d& p : points)
    if (out.empty() || (p - out.back()).norm() > 1e-6) out.push_back(p);
  while (out.size() > 1 && (out.front() - out.back()).norm() <= 1e-6) out.pop_back();
  return out;
}

double cross(const Vector2d& a, const Vector2d& b) { return a.x() * b.y() - a.y() * b.x(); }

// Whether segments ab and cd share a point (touching and overlapping count).
bool segments_meet(const Vector2d& a, const Vector2d& b, const Vector2d& c, const Vector2d& d) {
  const double eps = 1e-9 * std::max({1.0, a.norm(), b.norm(), c.norm(), d.norm()});
  const double d1 = cross(b - a, c - a), d2 = cross(b - a, d - a), d3 = cross(d - c, a - c), d4 = cross(d - c, b - c);
  const auto between = [&](const Vector2d& p, const Vector2d& q, const Vector2d& r) {  // r on pq's box
    return std::min(p.x(), q.x()) - eps <= r.x() && r.x() <= std::max(p.x(), q.x()) + eps &&
           std::min(p.y(), q.y()) - eps <= r.y() && r.y() <= std::max(p.y(), q.y()) + eps;
  };
  if (((d1 > eps && d2 < -eps) || (d1 < -eps && d2 > eps)) && ((d3 > eps && d4 < -eps) || (d3 < -eps && d4 > eps)))
    return true;
  return (std::abs(d1) <= eps && between(a, b, c)) || (std::abs(d2) <= eps && between(a, b, d)) ||
         (std::abs(d3) <= eps && between(c, d, a)) || (std::abs(d4) <= eps && between(c, d, b));
}

// The first pair of non-adjacent edges that meet, or (-1, -1); (-2, -2) when the contour is too
// tangled to check within the bounds below (its edges span the contour many times over). Edges
// are binned on a grid of about n cells so that a contour of 100,000 points is checked in linear
// time on average.
constexpr std::size_t kMaxBinnedEdges = 20'000'000;  // edge-cell entries
constexpr std::size_t kMaxEdgePairs = 50'000'000;    // pairs tested
std::pair<long, long> first_crossing(const std::vector<Vector2d>& p) {
  const long n = static_cast<long>(p.size());
  Vector2d lo = p[0], hi = p[0];
  for (const Vector2d& q : p) {
    lo = lo.cwiseMin(q);
    hi = hi.cwiseMax(q);
  }
  const long cells = std::max(1L, static_cast<long>(std::sqrt(double(n))));
  const Vector2d cell = ((hi - lo) / double(cells)).cwiseMax(Vector2d::Constant(1e-9));
  std::map<std::pair<long, long>, std::vector<long>> bins;
  const auto cell_of = [&](double v, int axis) {
    return static_cast<long>(std::clamp((v - lo[axis]) / cell[axis], 0.0, double(cells - 1)));
  };
  std::size_t binned = 0, tested = 0;
  for (long e = 0; e < n; ++e) {
    const Vector2d& a = p[std::size_t(e)];
    const Vector2d& b = p[std::size_t((e + 1) % n)];
    for (long x = cell_of(std::min(a.x(), b.x()), 0); x <= cell_of(std::max(a.x(), b.x()), 0); ++x)
      for (long y = cell_of(std::min(a.y(), b.y()), 1); y <= cell_of(std::max(a.y(), b.y()), 1); ++y) {
        if (++binned > kMaxBinnedEdges) return {-2, -2};
        bins[{x, y}].push_back(e);
      }
  }
  for (const auto& [key, edges] : bins) {
    for (std::size_t u = 0; u < edges.size(); ++u) {
      for (std::size_t v = u + 1; v < edges.size(); ++v) {
        if (++tested > kMaxEdgePairs) return {-2, -2};
        const long e = std::min(edges[u], edges[v]), f = std::max(edges[u], edges[v]);
        if (f == e + 1 || (e == 0 && f == n - 1)) continue;  // neighbours share a corner
        if (segments_meet(p[std::size_t(e)], p[std::size_t((e + 1) % n)], p[std::size_t(f)], p[std::size_t((f + 1) % n)]))
          return {e, f};
      }
    }
  }
  return {-1, -1};
}

}  // namespace

Status check_target_polygons(const std::vector<TargetPolygon>& polygons, const std::string& name) {
  if (polygons.empty()) return invalid_argument("target '" + name + "' has no contour");
  for (std::size_t c = 0; c < polygons.size(); ++c) {
    for (const Vector3d& q : polygons[c].points_ct_mm)
      if (!q.allFinite()) return invalid_argument(contour_name(name, c) + ": a point that is not a finite number");
    const std::vector<Vector3d> p = without_repeats(polygons[c].points_ct_mm);
    std::set<std::array<long long, 3>> distinct;  // to a micrometre
    for (const Vector3d& q : p)
      distinct.insert({std::llround(q.x() * 1e3), std::llround(q.y() * 1e3), std::llround(q.z() * 1e3)});
    if (distinct.size() < 3) {
      return invalid_argument(contour_name(name, c) + " has " + std::to_string(distinct.size()) +
                              " distinct point(s): a closed contour needs at least 3");
    }
    // The plane: through the centroid, normal to the points' least spread (a bow tie has no
    // area to give Newell's normal a direction, and must be called what it is).
    Vector3d centre = Vector3d::Zero();
    for (const Vector3d& q : p) centre += q;
    centre /= double(p.size());
    Eigen::Matrix3d spread = Eigen::Matrix3d::Zero();
    for (const Vector3d& q : p) spread += (q - centre) * (q - centre).transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(spread);
    const Vector3d unit = eigen.eigenvectors().col(0);
    for (std::size_t i = 0; i < p.size(); ++i) {
      const double off = std::abs(unit.dot(p[i] - centre));
      if (off > kPlanarToleranceMm) {
        std::ostringstream m;
        m << contour_name(name, c) << " is not planar: point " << i + 1 << " lies " << off
          << " mm off its plane (a closed planar contour lies in one slice)";
        return invalid_argument(m.str());
      }
    }
    const Vector3d u = eigen.eigenvectors().col(2), v = unit.cross(u);
    std::vector<Vector2d> flat;
    for (const Vector3d& q : p) flat.emplace_back(u.dot(q - centre), v.dot(q - centre));
    if (const auto [e, f] = first_crossing(flat); e == -2) {
      return invalid_argument(contour_name(name, c) + " is too tangled to check (" + std::to_string(p.size()) +
                              " points whose edges span the contour many times over): no target is drawn so");
    } else if (e >= 0) {
      return invalid_argument(contour_name(name, c) + " crosses itself (edge " + std::to_string(e + 1) + " meets edge " +
                              std::to_string(f + 1) + "): a self-crossing contour has no inside");
    }
    const double area_mm2 = 0.5 * newell_normal(p).norm();
    if (!(area_mm2 > 1e-3)) return invalid_argument(contour_name(name, c) + " encloses no area (its points lie on a line)");
  }
  return {};
}

TargetBox target_box(const std::vector<TargetPolygon>& polygons) {
  TargetBox box;
  bool first = true;
  for (const TargetPolygon& polygon : polygons) {
    for (const Vector3d& q : polygon.points_ct_mm) {
      box.min_ct_mm = first ? q : box.min_ct_mm.cwiseMin(q);
      box.max_ct_mm = first ? q : box.max_ct_mm.cwiseMax(q);
      first = false;
    }
  }
  return box;
}

double TargetMask::volume_cc() const {
  return double(voxels_inside) * geometry.spacing_mm.prod() / 1000.0;
}

Result<TargetMask> rasterise_target(const std::vector<TargetPolygon>& polygons, const tracking::VolumeGeometry& grid,
                                    const std::string& name) {
  LFTRACK_RETURN_IF_ERROR(check_target_polygons(polygons, name));
  TargetMask mask;
  mask.geometry = grid;
  mask.inside.assign(std::size_t(grid.voxel_count()), 0);
  const Eigen::Affine3d index_from_ct = grid.index_from_ct();
  const Vector3d k_axis = grid.direction.col(2);
  // The polygons of each slice, in continuous (i, j) index coordinates.
  std::map<int, std::vector<std::vector<Vector2d>>> slices;
  for (std::size_t c = 0; c < polygons.size(); ++c) {
    const std::vector<Vector3d> p = without_repeats(polygons[c].points_ct_mm);
    if (std::abs(newell_normal(p).normalized().dot(k_axis)) < 0.999) {
      return invalid_argument(contour_name(name, c) +
                              " does not lie in one of the CT's slices (its plane is tilted from the slices by more than "
                              "2.5 degrees): contour the target on the planning CT's axial slices");
    }
    const double kf = (index_from_ct * p[0]).z();
    if (!(kf > -0.5 && kf < grid.size.z() - 0.5)) {  // beyond the scan: in the box, not in the mask
      ++mask.contours_beyond_scan;
      continue;
    }
    const long k = std::lround(kf);
    mask.most_off_slice_mm = std::max(mask.most_off_slice_mm, std::abs(kf - double(k)) * grid.spacing_mm.z());
    std::vector<Vector2d> flat;
    for (const Vector3d& q : p) flat.push_back((index_from_ct * q).head<2>());
    for (const auto& other : slices[int(k)]) {
      if (other.size() != flat.size()) continue;
      bool same = true;
      for (std::size_t i = 0; i < flat.size() && same; ++i) same = (other[i] - flat[i]).norm() < 1e-6;
      if (same)
        return invalid_argument(contour_name(name, c) +
                                " repeats another contour of its slice: two equal contours enclose nothing together "
                                "(a contour inside another is a hole)");
    }
    slices[int(k)].push_back(std::move(flat));
  }
  std::vector<double> crossings;
  for (const auto& [k, polys] : slices) {
    double lo = 1e300, hi = -1e300;
    for (const auto& poly : polys)
      for (const Vector2d& q : poly) {
        lo = std::min(lo, q.y());
        hi = std::max(hi, q.y());
      }
    // Clamped in double before the casts: a contour may reach far beyond the grid.
    const int j0 = int(std::clamp(std::ceil(lo), 0.0, double(grid.size.y()))),
              j1 = int(std::clamp(std::floor(hi), -1.0, double(grid.size.y() - 1)));
    for (int j = j0; j <= j1; ++j) {
      crossings.clear();
      for (const auto& poly : polys) {
        for (std::size_t e = 0; e < poly.size(); ++e) {
          const Vector2d& a = poly[e];
          const Vector2d& b = poly[(e + 1) % poly.size()];
          if ((a.y() <= j) == (b.y() <= j)) continue;  // half-open: a vertex on the row counts once
          crossings.push_back(a.x() + (j - a.y()) * (b.x() - a.x()) / (b.y() - a.y()));
        }
      }
      std::sort(crossings.begin(), crossings.end());
      for (std::size_t m = 0; m + 1 < crossings.size(); m += 2) {
        const int i0 = int(std::clamp(std::ceil(crossings[m]), 0.0, double(grid.size.x()))),
                  i1 = int(std::clamp(std::floor(crossings[m + 1]), -1.0, double(grid.size.x() - 1)));
        for (int i = i0; i <= i1; ++i) {
          std::uint8_t& voxel = mask.inside[std::size_t(i + std::int64_t{grid.size.x()} * (j + std::int64_t{grid.size.y()} * k))];
          if (!voxel) {
            ++mask.voxels_inside;
            mask.lo_index = mask.lo_index.cwiseMin(Eigen::Vector3i(i, j, k));
            mask.hi_index = mask.hi_index.cwiseMax(Eigen::Vector3i(i, j, k));
          }
          voxel = 1;
        }
      }
    }
  }
  return mask;
}

}  // namespace lftrack::session
