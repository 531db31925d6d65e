#include "lftrack/calib/marker_detection.hpp"

#include <Eigen/Dense>
#include <cmath>
#include <sstream>

namespace lftrack::calib {

using tracking::ImageView;

namespace {

struct DiscRing {
  double disc = 0, ring = 0;
  bool ok = false;
};

// Mean over the disc r <= a and over the ring b <= r <= c around (col, row).
DiscRing disc_and_ring(const ImageView<const float>& im, const ImageView<const unsigned char>& valid, int col,
                       int row, double a, double b, double c) {
  const int reach = static_cast<int>(std::ceil(c));
  double sd = 0, sr = 0;
  int nd = 0, nr = 0;
  for (int dr = -reach; dr <= reach; ++dr) {
    const int r = row + dr;
    if (r < 0 || r >= im.rows) continue;
    for (int dc = -reach; dc <= reach; ++dc) {
      const int cc = col + dc;
      if (cc < 0 || cc >= im.cols) continue;
      if (!valid.empty() && valid.at(r, cc) == 0) continue;
      const float v = im.at(r, cc);
      if (!std::isfinite(v)) continue;
      const double d2 = dr * dr + dc * dc;
      if (d2 <= a * a) {
        sd += v;
        ++nd;
      } else if (d2 >= b * b && d2 <= c * c) {
        sr += v;
        ++nr;
      }
    }
  }
  DiscRing out;
  out.ok = nd > 0 && nr > 4;
  if (out.ok) {
    out.disc = sd / nd;
    out.ring = sr / nr;
  }
  return out;
}

}  // namespace

Result<MarkerDetection> find_marker(const ImageView<const float>& image,
                                              const ImageView<const unsigned char>& valid,
                                              const MarkerSearch& s) {
  if (image.empty()) return invalid_argument("marker search: empty image");
  if (!valid.empty() && (valid.rows != image.rows || valid.cols != image.cols))
    return invalid_argument("marker search: mask size differs from the image's");
  if (!s.expected_px.allFinite() || !(s.search_radius_px >= 0) || !(s.marker_radius_px > 0))
    return invalid_argument("marker search: expected position, radii must be finite and positive");
  const double a = std::max(1.0, s.marker_radius_px);
  const double b = a + 2, c = a + 5;
  int best_col = -1, best_row = -1;
  double best = -1e300, best_ring = 0;
  const int r0 = static_cast<int>(std::floor(s.expected_px.y() - s.search_radius_px));
  const int r1 = static_cast<int>(std::ceil(s.expected_px.y() + s.search_radius_px));
  const int c0 = static_cast<int>(std::floor(s.expected_px.x() - s.search_radius_px));
  const int c1 = static_cast<int>(std::ceil(s.expected_px.x() + s.search_radius_px));
  for (int row = std::max(r0, 0); row <= std::min(r1, image.rows - 1); ++row) {
    for (int col = std::max(c0, 0); col <= std::min(c1, image.cols - 1); ++col) {
      if ((Eigen::Vector2d(col, row) - s.expected_px).norm() > s.search_radius_px) continue;
      const DiscRing dr = disc_and_ring(image, valid, col, row, a, b, c);
      if (!dr.ok) continue;
      if (dr.disc - dr.ring > best) {
        best = dr.disc - dr.ring;
        best_col = col;
        best_row = row;
        best_ring = dr.ring;
      }
    }
  }
  std::ostringstream where;
  where << "near (" << s.expected_px.x() << ", " << s.expected_px.y() << ") within " << s.search_radius_px << " px";
  if (best_col < 0) return not_found("marker search: no usable pixels " + where.str());
  if (best < s.min_contrast) {
    std::ostringstream m;
    m << "marker search: no marker " << where.str() << " (best contrast " << best << " < " << s.min_contrast << ")";
    return not_found(m.str());
  }
  // Background under the marker: a plane fitted to the ring (bone edges and gradients would
  // otherwise pull the centroid).
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  const int ring_reach = static_cast<int>(std::ceil(c));
  for (int dr = -ring_reach; dr <= ring_reach; ++dr) {
    for (int dc = -ring_reach; dc <= ring_reach; ++dc) {
      const int r = best_row + dr, cc = best_col + dc;
      const double d2 = dr * dr + dc * dc;
      if (r < 0 || r >= image.rows || cc < 0 || cc >= image.cols || d2 < b * b || d2 > c * c) continue;
      if ((!valid.empty() && valid.at(r, cc) == 0) || !std::isfinite(image.at(r, cc))) continue;
      const Eigen::Vector3d row_vec(1.0, dc, dr);
      ata += row_vec * row_vec.transpose();
      atb += row_vec * double(image.at(r, cc));
    }
  }
  Eigen::Vector3d plane(best_ring, 0, 0);
  if (std::abs(ata.determinant()) > 1e-9) plane = ata.ldlt().solve(atb);
  auto background = [&](double col, double row) {
    return plane(0) + plane(1) * (col - best_col) + plane(2) * (row - best_row);
  };
  // Centroid of the intensity above that plane over a disc around the current estimate,
  // re-centred until it settles.
  const double reach = a + 1.5;
  Eigen::Vector2d centre(best_col, best_row);
  for (int iteration = 0; iteration < 8; ++iteration) {
    double sw = 0, sc = 0, sr = 0;
    const int r_lo = int(std::floor(centre.y() - reach)), r_hi = int(std::ceil(centre.y() + reach));
    const int c_lo = int(std::floor(centre.x() - reach)), c_hi = int(std::ceil(centre.x() + reach));
    for (int r = std::max(r_lo, 0); r <= std::min(r_hi, image.rows - 1); ++r) {
      for (int cc = std::max(c_lo, 0); cc <= std::min(c_hi, image.cols - 1); ++cc) {
        if ((Eigen::Vector2d(cc, r) - centre).norm() > reach) continue;
        if (!valid.empty() && valid.at(r, cc) == 0) continue;
        const double w = image.at(r, cc) - background(cc, r);
        if (!(w > 0)) continue;
        sw += w;
        sc += w * cc;
        sr += w * r;
      }
    }
    if (!(sw > 0)) break;
    const Eigen::Vector2d next(sc / sw, sr / sw);
    const bool settled = (next - centre).norm() < 1e-4;
    centre = next;
    if (settled) break;
  }
  MarkerDetection d;
  d.contrast = best;
  d.pixel = centre;
  return d;
}

}  // namespace lftrack::calib
