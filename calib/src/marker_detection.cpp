#include "lftrack/calib/marker_detection.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <sstream>

namespace lftrack::calib {

using tracking::ImageView;

namespace {

// Share of a candidate's contrast over the ring's plane that must remain over the ring's brightest
// sector, after the plane (a background gradient, a soft edge) is taken out of both: a compact
// blob keeps nearly all of it, a ridge through the disc almost none.
constexpr double kBlobShare = 0.5;
constexpr double kPi = 3.14159265358979323846;
constexpr double kMaxMarkerRadiusPx = 100;
constexpr double kMaxCoordinatePx = 1e6;

struct DiscRing {
  double disc = 0, ring = 0;
  double disc_over_plane = 0;      // disc mean minus the plane fitted to the ring, over the disc
  double brightest_sector = 0;     // the largest mean residual over that plane of the ring's sectors
  bool ok = false;
};
constexpr int kSectors = 8;

// Mean over the disc r <= a and over the ring b <= r <= c around (col, row), and per sector of
// the ring.
DiscRing disc_and_ring(const ImageView<const float>& im, const ImageView<const unsigned char>& valid, int col,
                       int row, double a, double b, double c) {
  const int reach = static_cast<int>(std::ceil(c));
  double sd = 0, sr = 0, sd_x = 0, sd_y = 0;
  int nd = 0, nr = 0;
  double sector_sum[kSectors] = {}, sector_x[kSectors] = {}, sector_y[kSectors] = {};
  int sector_n[kSectors] = {};
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();  // the ring's plane v = p0 + p1 dc + p2 dr
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
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
        sd_x += dc;
        sd_y += dr;
        ++nd;
      } else if (d2 >= b * b && d2 <= c * c) {
        sr += v;
        ++nr;
        const double angle = std::atan2(double(dr), double(dc)) + kPi;  // [0, 2 pi]
        const int k = std::min(kSectors - 1, static_cast<int>(angle / (2 * kPi) * kSectors));
        sector_sum[k] += v;
        sector_x[k] += dc;
        sector_y[k] += dr;
        ++sector_n[k];
        const Eigen::Vector3d row_vec(1.0, dc, dr);
        ata += row_vec * row_vec.transpose();
        atb += row_vec * double(v);
      }
    }
  }
  DiscRing out;
  out.ok = nd > 0 && nr > 4;
  if (out.ok) {
    out.disc = sd / nd;
    out.ring = sr / nr;
    Eigen::Vector3d plane(out.ring, 0, 0);
    if (std::abs(ata.determinant()) > 1e-9) plane = ata.ldlt().solve(atb);
    out.disc_over_plane = out.disc - (plane(0) + (plane(1) * sd_x + plane(2) * sd_y) / nd);
    out.brightest_sector = -1e300;
    for (int k = 0; k < kSectors; ++k)
      if (sector_n[k] > 0)
        out.brightest_sector =
            std::max(out.brightest_sector,
                     (sector_sum[k] - plane(0) * sector_n[k] - plane(1) * sector_x[k] - plane(2) * sector_y[k]) /
                         sector_n[k]);
  }
  return out;
}

// 3 x 3 median of the usable pixels of `im` over rows [r0, r1] x cols [c0, c1] (NaN where none is
// usable), so a stuck pixel or a one-pixel bad line cannot pose as a marker.
tracking::Image<float> median3(const ImageView<const float>& im, const ImageView<const unsigned char>& valid, int r0,
                               int r1, int c0, int c1) {
  tracking::Image<float> out(r1 - r0 + 1, c1 - c0 + 1, std::nanf(""));
  float values[9];
  for (int r = r0; r <= r1; ++r)
    for (int c = c0; c <= c1; ++c) {
      int n = 0;
      for (int dr = -1; dr <= 1; ++dr)
        for (int dc = -1; dc <= 1; ++dc) {
          const int rr = r + dr, cc = c + dc;
          if (rr < 0 || rr >= im.rows || cc < 0 || cc >= im.cols) continue;
          if (!valid.empty() && valid.at(rr, cc) == 0) continue;
          const float v = im.at(rr, cc);
          if (std::isfinite(v)) values[n++] = v;
        }
      if (n == 0) continue;
      std::nth_element(values, values + n / 2, values + n);
      out.at(r - r0, c - c0) = values[n / 2];
    }
  return out;
}

}  // namespace

Result<MarkerDetection> find_marker(const ImageView<const float>& image,
                                    const ImageView<const unsigned char>& valid, const MarkerSearch& s) {
  if (image.empty()) return invalid_argument("marker search: empty image");
  if (!valid.empty() && (valid.rows != image.rows || valid.cols != image.cols))
    return invalid_argument("marker search: mask size differs from the image's");
  if (!s.expected_px.allFinite() || !(s.search_radius_px >= 0) || !(s.marker_radius_px > 0) ||
      !std::isfinite(s.search_radius_px) || !std::isfinite(s.marker_radius_px) || !std::isfinite(s.min_contrast))
    return invalid_argument("marker search: expected position, radii and contrast must be finite, radii positive");
  if (s.marker_radius_px > kMaxMarkerRadiusPx)
    return invalid_argument("marker search: a marker radius over " + std::to_string(int(kMaxMarkerRadiusPx)) +
                            " px is not a marker");
  if (std::abs(s.expected_px.x()) > kMaxCoordinatePx || std::abs(s.expected_px.y()) > kMaxCoordinatePx)
    return not_found("marker search: the expected position lies far outside the image");
  // Beyond the image's diagonal a larger radius finds nothing more.
  const double search_radius_px =
      std::min(s.search_radius_px, std::hypot(double(image.rows), double(image.cols)));
  const double a = std::max(1.0, s.marker_radius_px);
  const double b = a + 2, c = a + 5;
  int best_col = -1, best_row = -1;
  double best = -1e300, best_ring = 0;
  int not_compact = 0;  // candidates brighter along a line than the ring around them
  const int r0 = static_cast<int>(std::floor(s.expected_px.y() - search_radius_px));
  const int r1 = static_cast<int>(std::ceil(s.expected_px.y() + search_radius_px));
  const int c0 = static_cast<int>(std::floor(s.expected_px.x() - search_radius_px));
  const int c1 = static_cast<int>(std::ceil(s.expected_px.x() + search_radius_px));
  // The search runs on the 3 x 3 median of the area (plus the ring's reach); the centroid below
  // on the image itself, where a pixel far from its median counts at the median.
  const int reach_px = static_cast<int>(std::ceil(c)) + 1;
  const int mr0 = std::max(0, r0 - reach_px), mr1 = std::min(image.rows - 1, r1 + reach_px);
  const int mc0 = std::max(0, c0 - reach_px), mc1 = std::min(image.cols - 1, c1 + reach_px);
  if (mr0 > mr1 || mc0 > mc1) return not_found("marker search: the search area lies outside the image");
  const tracking::Image<float> median = median3(image, valid, mr0, mr1, mc0, mc1);
  const ImageView<const float> search_image = median.view();
  for (int row = std::max(r0, 0); row <= std::min(r1, image.rows - 1); ++row) {
    for (int col = std::max(c0, 0); col <= std::min(c1, image.cols - 1); ++col) {
      if ((Eigen::Vector2d(col, row) - s.expected_px).norm() > search_radius_px) continue;
      const DiscRing dr = disc_and_ring(search_image, {}, col - mc0, row - mr0, a, b, c);
      if (!dr.ok) continue;
      // A marker is brighter than its whole ring; a ridge through the disc is as bright as the
      // ring's sectors along it (both over the ring's plane, so a gradient or a soft edge under a
      // marker does not count against it).
      if (dr.disc_over_plane - dr.brightest_sector < kBlobShare * dr.disc_over_plane) {
        if (dr.disc - dr.ring >= s.min_contrast) ++not_compact;
        continue;
      }
      if (dr.disc - dr.ring > best) {
        best = dr.disc - dr.ring;
        best_col = col;
        best_row = row;
        best_ring = dr.ring;
      }
    }
  }
  std::ostringstream where;
  where << "near (" << s.expected_px.x() << ", " << s.expected_px.y() << ") within " << search_radius_px
        << " px";
  if (best_col < 0 && not_compact > 0)
    return not_found("marker search: nothing blob-like " + where.str() + " (only edges and ridges)");
  if (best_col < 0) return not_found("marker search: no usable pixels " + where.str());
  if (best < s.min_contrast) {
    std::ostringstream m;
    m << "marker search: no marker " << where.str() << " (best contrast " << best << " < " << s.min_contrast
      << ")";
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
        // A pixel far from its 3 x 3 median (stuck, or on a bad line) counts at the median.
        double value = image.at(r, cc);
        const bool in_median = r >= mr0 && r <= mr1 && cc >= mc0 && cc <= mc1;
        const double m = in_median ? double(median.at(r - mr0, cc - mc0)) : value;
        if (!std::isfinite(value) || (std::isfinite(m) && std::abs(value - m) > 0.5 * best)) value = m;
        const double w = value - background(cc, r);
        if (!(w > 0) || !std::isfinite(w)) continue;
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
  if (!centre.allFinite()) return not_found("marker search: the marker's centroid is not finite " + where.str());
  MarkerDetection d;
  d.contrast = best;
  d.pixel = centre;
  return d;
}

}  // namespace lftrack::calib

namespace lftrack::calib {

namespace {

// Mean of `image` over a (2h+1)^2 box around every pixel (clamped at the edges), from an
// integral image.
std::vector<double> box_mean(const ImageView<const float>& im, int h) {
  const int rows = im.rows, cols = im.cols;
  std::vector<double> integral(std::size_t(rows + 1) * (cols + 1), 0.0);
  auto at = [&](int r, int c) -> double& { return integral[std::size_t(r) * (cols + 1) + c]; };
  for (int r = 0; r < rows; ++r) {
    double row_sum = 0;
    for (int c = 0; c < cols; ++c) {
      const float v = im.at(r, c);
      row_sum += std::isfinite(v) ? v : 0.0;
      at(r + 1, c + 1) = at(r, c + 1) + row_sum;
    }
  }
  std::vector<double> mean(std::size_t(rows) * cols);
  for (int r = 0; r < rows; ++r) {
    const int r0 = std::max(0, r - h), r1 = std::min(rows, r + h + 1);
    for (int c = 0; c < cols; ++c) {
      const int c0 = std::max(0, c - h), c1 = std::min(cols, c + h + 1);
      const double sum = at(r1, c1) - at(r0, c1) - at(r1, c0) + at(r0, c0);
      mean[std::size_t(r) * cols + c] = sum / double((r1 - r0) * (c1 - c0));
    }
  }
  return mean;
}

}  // namespace

Result<MarkerScanResult> scan_markers(const ImageView<const float>& image, const MarkerScan& scan) {
  if (image.empty()) return invalid_argument("marker scan: empty image");
  if (!(scan.marker_radius_px >= 1) || !(scan.marker_radius_px <= 100) || !(scan.min_contrast > 0) ||
      !(scan.noise_sigmas > 0) || scan.border_px < 0) {
    return invalid_argument("marker scan: radius must be in [1, 100] px, contrast and noise sigmas positive");
  }
  const int rows = image.rows, cols = image.cols;
  const double radius = scan.marker_radius_px;
  // High-pass: the image minus its mean over a box three marker diameters wide.
  const std::vector<double> local = box_mean(image, static_cast<int>(std::ceil(3 * radius)));
  std::vector<float> high(std::size_t(rows) * cols);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const float v = image.at(r, c);
      high[std::size_t(r) * cols + c] = std::isfinite(v) ? float(v - local[std::size_t(r) * cols + c]) : 0.f;
    }
  // Robust noise level: 1.4826 * median absolute deviation of the high-passed image.
  std::vector<float> sorted = high;
  const std::size_t mid = sorted.size() / 2;
  std::nth_element(sorted.begin(), sorted.begin() + std::ptrdiff_t(mid), sorted.end());
  const float median = sorted[mid];
  for (float& v : sorted) v = std::abs(v - median);
  std::nth_element(sorted.begin(), sorted.begin() + std::ptrdiff_t(mid), sorted.end());
  const double sigma = 1.4826 * sorted[mid];
  // A disc of contrast k over the local mean raises the high-passed centre by about k * 0.9;
  // half of the peak marks the blob.
  const double threshold = std::max(scan.min_contrast, scan.noise_sigmas * sigma) * 0.5;

  MarkerScanResult out;
  const double disc_area = 3.14159265358979 * radius * radius;
  std::vector<unsigned char> seen(high.size(), 0);
  std::vector<int> stack;
  for (int r0 = 0; r0 < rows; ++r0) {
    for (int c0 = 0; c0 < cols; ++c0) {
      const std::size_t i0 = std::size_t(r0) * cols + c0;
      if (seen[i0] || high[i0] < threshold) continue;
      // Flood fill (4-connected) the blob of pixels above threshold.
      int count = 0, rmin = r0, rmax = r0, cmin = c0, cmax = c0;
      double sw = 0, sc = 0, sr = 0, scc = 0, srr = 0, scr = 0, peak = 0;
      stack.assign(1, int(i0));
      seen[i0] = 1;
      while (!stack.empty()) {
        const int i = stack.back();
        stack.pop_back();
        const int r = i / cols, c = i % cols;
        const double w = high[std::size_t(i)];
        ++count;
        peak = std::max(peak, w);
        sw += w;
        sc += w * c;
        sr += w * r;
        scc += w * c * c;
        srr += w * r * r;
        scr += w * c * r;
        rmin = std::min(rmin, r), rmax = std::max(rmax, r), cmin = std::min(cmin, c),
        cmax = std::max(cmax, c);
        const int next[4][2] = {{r - 1, c}, {r + 1, c}, {r, c - 1}, {r, c + 1}};
        for (const auto& n : next) {
          if (n[0] < 0 || n[0] >= rows || n[1] < 0 || n[1] >= cols) continue;
          const std::size_t j = std::size_t(n[0]) * cols + n[1];
          if (seen[j] || high[j] < threshold) continue;
          seen[j] = 1;
          stack.push_back(int(j));
        }
      }
      if (peak < 2 * threshold) {
        ++out.rejected_small;
        continue;
      }
      if (count < 0.2 * disc_area) {
        ++out.rejected_small;
        continue;
      }
      if (rmin < scan.border_px || cmin < scan.border_px || rmax >= rows - scan.border_px ||
          cmax >= cols - scan.border_px) {
        ++out.rejected_border;
        continue;
      }
      // Shape: weighted second moments; a merged pair is large or elongated.
      const double mc = sc / sw, mr = sr / sw;
      Eigen::Matrix2d cov;
      cov << scc / sw - mc * mc, scr / sw - mc * mr, scr / sw - mc * mr, srr / sw - mr * mr;
      const Eigen::Vector2d ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cov).eigenvalues();
      const bool elongated = ev(1) > 2.0 * std::max(ev(0), 1e-9);
      if (count > 2.5 * disc_area || elongated) {
        ++out.rejected_merged;
        continue;
      }
      MarkerSearch s;
      s.expected_px = {mc, mr};
      s.search_radius_px = 1.5;
      s.marker_radius_px = radius;
      s.min_contrast = threshold;
      auto found = find_marker(image, {}, s);
      if (!found.ok()) {
        ++out.rejected_small;
        continue;
      }
      out.markers.push_back(*found);
    }
  }
  return out;
}

}  // namespace lftrack::calib
