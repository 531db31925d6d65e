// roi.mask: the target's neighbourhood in each view (roi_mask.hpp).

#include "lftrack/host/roi_mask.hpp"

#include <algorithm>
#include <cmath>

#include "lftrack/host/dicom_registration.hpp"
#include "lftrack/host/patient_setup.hpp"

namespace lftrack::host {

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
  std::vector<tracking::Image<unsigned char>> masks;
  for (std::size_t v = 0; v < p.scene.detectors.size(); ++v) {
    const tracking::XrayView& view = p.scene.detectors[v].view;
    const tracking::PixelWindow& w = p.roi_windows[v];
    tracking::Image<unsigned char> mask(w.rows, w.cols, 0);
    for (int k = 0; k < g.size.z(); ++k)
      for (int j = 0; j < g.size.y(); ++j)
        for (int i = 0; i < g.size.x(); ++i) {
          if (!target->mask.inside[std::size_t(i) + std::size_t(g.size.x()) * (std::size_t(j) + std::size_t(g.size.y()) * std::size_t(k))])
            continue;
          double c0 = 1e300, c1 = -1e300, r0 = 1e300, r1 = -1e300;
          for (int corner = 0; corner < 8; ++corner) {
            const Vector3d index(i + ((corner & 1) ? 0.5 : -0.5), j + ((corner & 2) ? 0.5 : -0.5),
                                 k + ((corner & 4) ? 0.5 : -0.5));
            const auto px = view.project(p.nominal_T_room_from_ct * (ct_from_index * index));
            if (!px) continue;
            c0 = std::min(c0, px->x());
            c1 = std::max(c1, px->x());
            r0 = std::min(r0, px->y());
            r1 = std::max(r1, px->y());
          }
          const int rr0 = std::max(0, int(std::floor(r0 + 0.5)) - w.row0),
                    rr1 = std::min(w.rows - 1, int(std::ceil(r1 - 0.5)) - w.row0);
          const int cc0 = std::max(0, int(std::floor(c0 + 0.5)) - w.col0),
                    cc1 = std::min(w.cols - 1, int(std::ceil(c1 - 0.5)) - w.col0);
          for (int r = rr0; r <= rr1; ++r)
            for (int c = cc0; c <= cc1; ++c) mask.at(r, c) = 1;
        }
    if (std::none_of(mask.pixels().begin(), mask.pixels().end(), [](unsigned char b) { return b != 0; }))
      return failed_precondition(where + "target '" + spec.target + "' projects outside view " + view.name +
                                 "'s ROI window at the nominal pose");
    // The margin, from millimetres at the isocentre to pixels on the detector.
    const Vector3d origin_room = p.registration_origin_room_mm();
    const double magnification =
        (view.detector_centre_mm() - view.source_mm).norm() / (origin_room - view.source_mm).norm();
    grow(&mask, spec.margin_mm * magnification / std::min(view.pitch_row_mm, view.pitch_col_mm));
    masks.push_back(std::move(mask));
  }
  return masks;
}

}  // namespace lftrack::host
