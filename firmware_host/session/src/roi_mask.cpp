// roi.mask: the target's neighbourhood in each view (roi_mask.hpp).

#include "lftrack/session/roi_mask.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "lftrack/session/dicom_registration.hpp"
#include "lftrack/session/patient_setup.hpp"

namespace lftrack::session {

namespace {

using Eigen::Vector3d;

// Grows the 1-pixels of `mask` by `radius_px` (a chamfer distance, 3-4 weights: within 8 % of
// Euclidean), in place.
void grow(tracking::Image<unsigned char>* mask, double radius_px) {
  const int rows = mask->rows(), cols = mask->cols();
  constexpr int kFar = 1 << 28;
  std::vector<int> d(std::size_t(rows) * std::size_t(cols), kFar);
  const auto at = [&](int r, int c) -> int& { return d[std::size_t(r) * std::size_t(cols) + std::size_t(c)]; };
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
      if (mask->at(r, c)) at(r, c) = 0;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      int& v = at(r, c);
      if (c > 0) v = std::min(v, at(r, c - 1) + 3);
      if (r > 0) {
        v = std::min(v, at(r - 1, c) + 3);
        if (c > 0) v = std::min(v, at(r - 1, c - 1) + 4);
        if (c + 1 < cols) v = std::min(v, at(r - 1, c + 1) + 4);
      }
    }
  for (int r = rows - 1; r >= 0; --r)
    for (int c = cols - 1; c >= 0; --c) {
      int& v = at(r, c);
      if (c + 1 < cols) v = std::min(v, at(r, c + 1) + 3);
      if (r + 1 < rows) {
        v = std::min(v, at(r + 1, c) + 3);
        if (c + 1 < cols) v = std::min(v, at(r + 1, c + 1) + 4);
        if (c > 0) v = std::min(v, at(r + 1, c - 1) + 4);
      }
    }
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) mask->at(r, c) = at(r, c) <= 3.0 * radius_px ? 1 : 0;
}

std::string margin_text(double mm) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", mm);
  return text;
}

}  // namespace

Result<std::vector<tracking::Image<unsigned char>>> project_roi_mask(const PreparedScene& p) {
  if (!p.scene.roi.mask) return failed_precondition(p.scene.source + ": no roi.mask");
  const RoiMaskSpec& spec = *p.scene.roi.mask;
  const std::string where = p.scene.where("roi") + ": roi.mask: ";
  auto identity = read_ct_dicom_identity(p.scene.ct.path);
  if (!identity.ok())
    return Status(identity.status().code(), where + "the structure set is tied to its CT by the Frame of Reference, "
                                                    "which a DICOM series carries: " +
                                                identity.status().message());
  auto target = target_from_structure_set(spec.rtstruct, spec.target, *identity, p.ct->geometry);
  if (!target.ok()) return Status(target.status().code(), where + target.status().message());
  const tracking::VolumeGeometry& g = p.ct->geometry;
  const Eigen::Affine3d ct_from_index = g.ct_from_index();
  const Eigen::Vector3i& lo = target->mask.lo_index;  // the target's voxels: their box bounds the walk
  const Eigen::Vector3i& hi = target->mask.hi_index;
  std::vector<tracking::Image<unsigned char>> masks;
  for (std::size_t v = 0; v < p.scene.detectors.size(); ++v) {
    const tracking::XrayView& view = p.scene.detectors[v].view;
    const tracking::PixelWindow& w = p.roi_windows[v];
    // The margin, from millimetres at the isocentre to pixels on the detector; the target is drawn
    // into the window padded by it, so what lies just beyond the window still grows into it.
    const Vector3d origin_room = p.registration_origin_room_mm();
    const double magnification =
        (view.detector_centre_mm() - view.source_mm).norm() / (origin_room - view.source_mm).norm();
    const double margin_px = spec.margin_mm * magnification / std::min(view.pitch_row_mm, view.pitch_col_mm);
    const int pad = int(std::ceil(margin_px)) + 1;
    const int rows = w.rows + 2 * pad, cols = w.cols + 2 * pad;
    tracking::Image<unsigned char> padded(rows, cols, 0);
    // One projection matrix for the view, the CT's index frame to pixels (col, row).
    const tracking::Matrix34d P = view.projection() * (p.nominal_T_room_from_ct * ct_from_index).matrix();
    const auto pixel = [&](const Vector3d& index, Eigen::Vector2d* out) {
      const Vector3d h = P * index.homogeneous();
      if (!(h.z() > 1e-9)) return false;  // at or behind the source
      *out = h.head<2>() / h.z();
      return out->allFinite();
    };
    for (int k = lo.z(); k <= hi.z(); ++k)
      for (int j = lo.y(); j <= hi.y(); ++j)
        for (int i = lo.x(); i <= hi.x(); ++i) {
          if (!target->mask.inside[std::size_t(i) + std::size_t(g.size.x()) * (std::size_t(j) + std::size_t(g.size.y()) * std::size_t(k))])
            continue;
          double c0 = 1e300, c1 = -1e300, r0 = 1e300, r1 = -1e300;
          bool seen = false;
          for (int corner = 0; corner < 8; ++corner) {
            Eigen::Vector2d px;
            if (!pixel(Vector3d(i + ((corner & 1) ? 0.5 : -0.5), j + ((corner & 2) ? 0.5 : -0.5),
                                k + ((corner & 4) ? 0.5 : -0.5)),
                       &px))
              continue;
            seen = true;
            c0 = std::min(c0, px.x());
            c1 = std::max(c1, px.x());
            r0 = std::min(r0, px.y());
            r1 = std::max(r1, px.y());
          }
          if (!seen) continue;
          // Clamped in double before any cast: a corner near the source plane projects far away.
          const auto clamp_to = [](double x, int n) { return int(std::clamp(x, -1.0, double(n))); };
          const int rr0 = std::max(0, clamp_to(std::floor(r0 + 0.5) - w.row0 + pad, rows)),
                    rr1 = std::min(rows - 1, clamp_to(std::ceil(r1 - 0.5) - w.row0 + pad, rows));
          const int cc0 = std::max(0, clamp_to(std::floor(c0 + 0.5) - w.col0 + pad, cols)),
                    cc1 = std::min(cols - 1, clamp_to(std::ceil(c1 - 0.5) - w.col0 + pad, cols));
          for (int r = rr0; r <= rr1; ++r)
            for (int c = cc0; c <= cc1; ++c) padded.at(r, c) = 1;
        }
    grow(&padded, margin_px);
    tracking::Image<unsigned char> mask(w.rows, w.cols, 0);
    std::int64_t looked_at = 0;
    for (int r = 0; r < w.rows; ++r)
      for (int c = 0; c < w.cols; ++c) looked_at += (mask.at(r, c) = padded.at(r + pad, c + pad)) != 0;
    if (looked_at < kMinRoiMaskPixels)
      return failed_precondition(where + "target '" + spec.target + "' and its " + margin_text(spec.margin_mm) +
                                 " mm leave " + std::to_string(looked_at) + " pixels of view " + view.name +
                                 "'s ROI window at the nominal pose, fewer than the " +
                                 std::to_string(kMinRoiMaskPixels) +
                                 " a registration needs (a wider margin_mm, or no mask)");
    masks.push_back(std::move(mask));
  }
  return masks;
}

}  // namespace lftrack::session
