// The set-up picture of a new patient's scene (issue 53): see setup_picture.hpp.

#include "lftrack/session/setup_picture.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include "lftrack/tracking/drr_renderer.hpp"

namespace lftrack::session {

namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;
using Rgb = std::array<std::uint8_t, 3>;
constexpr Rgb kIsocentre{0, 255, 0};
constexpr Rgb kRoi{255, 255, 0};
constexpr Rgb kTarget{255, 0, 0};
constexpr Rgb kMask{0, 255, 255};

void put(tracking::RgbImage* image, double row, double col, const Rgb& c) {
  image->set(int(std::lround(row)), int(std::lround(col)), c[0], c[1], c[2]);
}

// A line from a to b, (col, row) pixel coordinates, drawn a pixel at a time.
void line(tracking::RgbImage* image, const Vector2d& a, const Vector2d& b, const Rgb& c) {
  const int steps = std::clamp(int(std::ceil((b - a).lpNorm<Eigen::Infinity>())), 1, 100000);
  for (int s = 0; s <= steps; ++s) {
    const Vector2d p = a + (b - a) * (double(s) / steps);
    put(image, p.y(), p.x(), c);
  }
}

void cross(tracking::RgbImage* image, const Vector2d& at, const Rgb& c, int arm = 7) {
  line(image, at - Vector2d(arm, 0), at + Vector2d(arm, 0), c);
  line(image, at - Vector2d(0, arm), at + Vector2d(0, arm), c);
}

std::array<Vector3d, 8> box_corners(const Vector3d& centre, const Vector3d& size) {
  std::array<Vector3d, 8> corners;
  for (int k = 0; k < 8; ++k)
    corners[std::size_t(k)] =
        centre + 0.5 * Vector3d((k & 1) ? 1 : -1, (k & 2) ? 1 : -1, (k & 4) ? 1 : -1).cwiseProduct(size);
  return corners;
}

// One view's DRR at the nominal pose, windowed to grey, with the marks projected on it.
Result<tracking::RgbImage> view_panel(const PreparedScene& p, int index, const SetupMarks& marks,
                                      const tracking::DrrRenderer& renderer, int panel_px) {
  const tracking::XrayView& detector = p.scene.detectors[std::size_t(index)].view;
  const double scale = std::min(1.0, double(panel_px) / std::max(detector.rows, detector.cols));
  const int rows = std::max(1, int(detector.rows * scale)), cols = std::max(1, int(detector.cols * scale));
  const tracking::XrayView view = detector.resampled(0, 0, detector.rows, detector.cols, rows, cols);
  tracking::Image<float> drr(rows, cols);
  LFTRACK_RETURN_IF_ERROR(renderer.render(p.nominal_T_room_from_ct, view, tracking::PixelWindow::full(rows, cols),
                                          drr.view(), nullptr));
  const tracking::DisplayWindow w = tracking::percentile_window(drr.view(), 0.5, 99.8);
  tracking::RgbImage image(rows, cols);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const double v = std::clamp((drr.at(r, c) - w.low) / std::max(1e-9, w.high - w.low), 0.0, 1.0);
      const auto g = static_cast<std::uint8_t>(std::lround(v * 255));
      image.set(r, c, g, g, g);
    }
  const auto project = [&](const Vector3d& ct_mm) { return view.project(p.nominal_T_room_from_ct * ct_mm); };
  const auto corners = box_corners(marks.roi_centre_ct_mm, marks.roi_size_mm);
  for (int a = 0; a < 8; ++a)
    for (int b = a + 1; b < 8; ++b) {
      if (__builtin_popcount(unsigned(a ^ b)) != 1) continue;  // an edge joins corners that differ on one axis
      const auto pa = project(corners[std::size_t(a)]), pb = project(corners[std::size_t(b)]);
      if (pa && pb) line(&image, *pa, *pb, kRoi);
    }
  for (const TargetPolygon& polygon : marks.target_polygons)
    for (std::size_t i = 0; i < polygon.points_ct_mm.size(); ++i) {
      const auto pa = project(polygon.points_ct_mm[i]);
      const auto pb = project(polygon.points_ct_mm[(i + 1) % polygon.points_ct_mm.size()]);
      if (pa && pb) line(&image, *pa, *pb, kTarget);
    }
  // roi.mask: the edge of what the measures look at (cyan), on the panel's pixels.
  if (std::size_t(index) < p.roi_masks.size()) {
    const tracking::Image<unsigned char>& mask = p.roi_masks[std::size_t(index)];
    const tracking::PixelWindow& window = p.roi_windows[std::size_t(index)];
    const auto looked_at = [&](int r, int c) {  // panel pixel -> detector pixel -> mask
      const int dr = int((r + 0.5) / scale) - window.row0, dc = int((c + 0.5) / scale) - window.col0;
      return dr >= 0 && dc >= 0 && dr < window.rows && dc < window.cols && mask.at(dr, dc) != 0;
    };
    for (int r = 1; r + 1 < rows; ++r)
      for (int c = 1; c + 1 < cols; ++c)
        if (looked_at(r, c) && !(looked_at(r - 1, c) && looked_at(r + 1, c) && looked_at(r, c - 1) && looked_at(r, c + 1)))
          put(&image, r, c, kMask);
  }
  if (const auto iso = project(marks.isocentre_ct_mm)) cross(&image, *iso, kIsocentre);
  return image;
}

// A slice of the CT through the isocentre, 0.5 mm a pixel: `right` and `down` are the CT-frame
// directions of the panel's columns and rows.
tracking::RgbImage slice_panel(const PreparedScene& p, const SetupMarks& marks, const Vector3d& right,
                               const Vector3d& down, int panel_px) {
  constexpr double kPixelMm = 0.5;
  const tracking::CtVolume& ct = *p.ct;
  const tracking::VolumeGeometry& g = ct.geometry;
  const Eigen::Affine3d index_from_ct = g.index_from_ct();
  tracking::RgbImage image(panel_px, panel_px);
  std::vector<std::uint8_t> inside(std::size_t(panel_px) * std::size_t(panel_px), 0);
  const auto at = [&](int r, int c) {
    return marks.isocentre_ct_mm + right * ((c - 0.5 * panel_px) * kPixelMm) + down * ((r - 0.5 * panel_px) * kPixelMm);
  };
  const auto voxel = [&](const Vector3d& ct_mm, Eigen::Vector3i* ijk) {
    const Vector3d index = index_from_ct * ct_mm;
    for (int a = 0; a < 3; ++a) {
      (*ijk)[a] = int(std::lround(index[a]));
      if ((*ijk)[a] < 0 || (*ijk)[a] >= g.size[a]) return false;
    }
    return true;
  };
  for (int r = 0; r < panel_px; ++r)
    for (int c = 0; c < panel_px; ++c) {
      Eigen::Vector3i ijk;
      if (!voxel(at(r, c), &ijk)) {
        image.set(r, c, 0, 0, 48);  // beyond the scan: dark blue, never mistaken for air
        continue;
      }
      const double v = std::clamp((ct.at(ijk.x(), ijk.y(), ijk.z()) + 400.0) / 1600.0, 0.0, 1.0);
      const auto grey = static_cast<std::uint8_t>(std::lround(v * 255));
      image.set(r, c, grey, grey, grey);
      if (marks.target) {
        const std::size_t n = std::size_t(ijk.x()) +
                              std::size_t(g.size.x()) * (std::size_t(ijk.y()) + std::size_t(g.size.y()) * std::size_t(ijk.z()));
        inside[std::size_t(r) * std::size_t(panel_px) + std::size_t(c)] = marks.target->inside[n];
      }
    }
  // The target's outline: inside pixels with an outside neighbour.
  for (int r = 1; r + 1 < panel_px; ++r)
    for (int c = 1; c + 1 < panel_px; ++c) {
      const auto in = [&](int rr, int cc) { return inside[std::size_t(rr) * std::size_t(panel_px) + std::size_t(cc)] != 0; };
      if (in(r, c) && !(in(r - 1, c) && in(r + 1, c) && in(r, c - 1) && in(r, c + 1))) put(&image, r, c, kTarget);
    }
  // The ROI's box where this plane cuts it, and the isocentre.
  const auto pixel_of = [&](const Vector3d& ct_mm) {
    const Vector3d d = ct_mm - marks.isocentre_ct_mm;
    return Vector2d(d.dot(right) / kPixelMm + 0.5 * panel_px, d.dot(down) / kPixelMm + 0.5 * panel_px);
  };
  const Vector3d half = 0.5 * marks.roi_size_mm;
  const Vector3d lo = marks.roi_centre_ct_mm - half, hi = marks.roi_centre_ct_mm + half;
  const Vector3d normal = right.cross(down);
  const double depth = marks.isocentre_ct_mm.dot(normal);
  const double box_lo = std::min(lo.dot(normal), hi.dot(normal)), box_hi = std::max(lo.dot(normal), hi.dot(normal));
  if (depth >= box_lo && depth <= box_hi) {
    const Vector3d a = lo - normal * (lo.dot(normal) - depth), b = hi - normal * (hi.dot(normal) - depth);
    const Vector2d pa = pixel_of(a), pb = pixel_of(b);
    line(&image, {pa.x(), pa.y()}, {pb.x(), pa.y()}, kRoi);
    line(&image, {pb.x(), pa.y()}, {pb.x(), pb.y()}, kRoi);
    line(&image, {pb.x(), pb.y()}, {pa.x(), pb.y()}, kRoi);
    line(&image, {pa.x(), pb.y()}, {pa.x(), pa.y()}, kRoi);
  }
  cross(&image, pixel_of(marks.isocentre_ct_mm), kIsocentre);
  return image;
}

void paste(tracking::RgbImage* into, const tracking::RgbImage& panel, int row0, int col0) {
  for (int r = 0; r < panel.rows; ++r)
    for (int c = 0; c < panel.cols; ++c) {
      const std::uint8_t* p = &panel.rgb[(std::size_t(r) * std::size_t(panel.cols) + std::size_t(c)) * 3];
      into->set(row0 + r, col0 + c, p[0], p[1], p[2]);
    }
}

}  // namespace

Result<tracking::RgbImage> setup_picture(const PreparedScene& p, const SetupMarks& marks, tracking::ThreadPool* pool,
                                         int panel_px) {
  if (!p.ct || !p.mu) return failed_precondition("the set-up picture needs the scene's CT");
  if (panel_px < 32 || panel_px > 2048) return invalid_argument("a set-up picture's panel is 32 to 2048 pixels");
  tracking::RendererOptions options;
  options.pool = pool;
  auto renderer = tracking::make_renderer("siddon", p.mu, options);
  if (!renderer.ok()) return renderer.status();
  std::vector<tracking::RgbImage> top;
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    auto panel = view_panel(p, int(i), marks, **renderer, panel_px);
    if (!panel.ok()) return panel.status();
    top.push_back(std::move(*panel));
  }
  // Patient axes in the CT frame (LPS): axial seen from the feet (the patient's right on the
  // left, anterior up), coronal and sagittal with the head up (sagittal: anterior on the left).
  const Vector3d left(1, 0, 0), posterior(0, 1, 0), inferior(0, 0, -1);
  const std::vector<tracking::RgbImage> bottom = {slice_panel(p, marks, left, posterior, panel_px),
                                                  slice_panel(p, marks, left, inferior, panel_px),
                                                  slice_panel(p, marks, posterior, inferior, panel_px)};
  constexpr int kGap = 4;
  int top_width = 0, top_height = 0;
  for (const auto& t : top) {
    top_width += t.cols + kGap;
    top_height = std::max(top_height, t.rows);
  }
  const int width = std::max(top_width, 3 * (panel_px + kGap)) - kGap;
  tracking::RgbImage picture(top_height + kGap + panel_px, width);
  std::fill(picture.rgb.begin(), picture.rgb.end(), std::uint8_t{32});
  int col = 0;
  for (const auto& t : top) {
    paste(&picture, t, 0, col);
    col += t.cols + kGap;
  }
  col = 0;
  for (const auto& b : bottom) {
    paste(&picture, b, top_height + kGap, col);
    col += b.cols + kGap;
  }
  return picture;
}

std::int64_t count_colour(const tracking::RgbImage& picture, std::uint8_t red, std::uint8_t green, std::uint8_t blue) {
  std::int64_t n = 0;
  for (std::size_t i = 0; i + 2 < picture.rgb.size(); i += 3)
    n += picture.rgb[i] == red && picture.rgb[i + 1] == green && picture.rgb[i + 2] == blue;
  return n;
}

}  // namespace lftrack::session
