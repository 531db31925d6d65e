#include "lftrack/calib/phantom_pose.hpp"

#include <algorithm>
#include <optional>
#include <vector>

#include "lftrack/calib/marker_detection.hpp"
#include "lftrack/calib/triangulation.hpp"

namespace lftrack::calib {

namespace {

// One pass: pair each ball's projection under `guess` with the only detection within `gate`
// (balls whose projections come within the gate of another's are skipped), triangulate the
// balls found in both views, drop triangulations whose rays miss by more than `max_gap_mm`
// (a wrong pairing), and fit the model to the rest.
Result<PhantomPose> one_pass(const CalibrationPhantom& phantom,
                             const std::array<tracking::XrayView, 2>& views,
                             const std::array<std::vector<MarkerDetection>, 2>& blobs,
                             const std::array<double, 2>& gate_px, const Eigen::Isometry3d& guess,
                             double max_gap_mm) {
  const std::size_t n = phantom.markers_mm.size();
  std::array<std::vector<std::optional<Eigen::Vector2d>>, 2> found;
  for (std::size_t k = 0; k < 2; ++k) {
    const double gate = gate_px[k];
    std::vector<std::optional<Eigen::Vector2d>> predicted(n);
    for (std::size_t i = 0; i < n; ++i) predicted[i] = views[k].project(guess * phantom.markers_mm[i]);
    found[k].assign(n, std::nullopt);
    for (std::size_t i = 0; i < n; ++i) {
      if (!predicted[i]) continue;
      bool crowded = false;
      for (std::size_t j = 0; j < n && !crowded; ++j) {
        crowded = j != i && predicted[j] && (*predicted[j] - *predicted[i]).norm() < gate;
      }
      if (crowded) continue;
      int best = -1, within = 0;
      double best_d = gate;
      for (std::size_t d = 0; d < blobs[k].size(); ++d) {
        const double dist = (blobs[k][d].pixel - *predicted[i]).norm();
        within += dist < gate;
        if (dist < best_d) {
          best_d = dist;
          best = int(d);
        }
      }
      if (best >= 0 && within == 1) found[k][i] = blobs[k][std::size_t(best)].pixel;
    }
  }
  std::vector<Eigen::Vector3d> model, measured;
  PhantomPose out;
  for (std::size_t i = 0; i < n; ++i) {
    if (!found[0][i] || !found[1][i]) continue;
    auto point = triangulate(views[0], *found[0][i], views[1], *found[1][i]);
    if (!point.ok() || point->gap_mm > max_gap_mm) continue;
    model.push_back(phantom.markers_mm[i]);
    measured.push_back(point->point_mm);
    out.max_ray_gap_mm = std::max(out.max_ray_gap_mm, point->gap_mm);
  }
  if (model.size() < 4) {
    return not_found(
        "phantom pose: only " + std::to_string(model.size()) +
        " balls found in both views (need 4); is the phantom in the field and the guess within 5 mm?");
  }
  auto fit = fit_rigid(model, measured);
  if (!fit.ok()) return fit.status().with_context("phantom pose");
  out.T_room_from_phantom = fit->T_to_from;
  out.fre_rms_mm = fit->fre_rms_mm;
  out.markers = int(model.size());
  return out;
}

}  // namespace

Result<PhantomPose> measure_phantom_pose(const CalibrationPhantom& phantom,
                                         const std::array<tracking::XrayView, 2>& views,
                                         const std::array<tracking::ImageView<const float>, 2>& images,
                                         const Eigen::Isometry3d& T_guess) {
  LFTRACK_RETURN_IF_ERROR(phantom.validate());
  std::array<std::vector<MarkerDetection>, 2> blobs;
  std::array<double, 2> radius_px{};
  for (std::size_t k = 0; k < 2; ++k) {
    const tracking::XrayView& v = views[k];
    LFTRACK_RETURN_IF_ERROR(v.validate());
    if (images[k].rows != v.rows || images[k].cols != v.cols) {
      return invalid_argument("phantom pose: image " + std::to_string(k) +
                              " differs in size from its detector");
    }
    MarkerScan scan;
    scan.marker_radius_px = projected_ball_radius_px(phantom, v, T_guess.translation());
    radius_px[k] = scan.marker_radius_px;
    auto found = scan_markers(images[k], scan);
    if (!found.ok()) return found.status();
    blobs[k] = std::move(found->markers);
  }
  // Coarse: a wide gate around the guess, wrong pairings weeded out by their rays' miss
  // distance; fine: a tight gate around the coarse pose.
  auto coarse = one_pass(phantom, views, blobs, {6 * radius_px[0], 6 * radius_px[1]}, T_guess, 1.0);
  if (!coarse.ok()) return coarse.status();
  return one_pass(phantom, views, blobs, {2.5 * radius_px[0], 2.5 * radius_px[1]},
                  coarse->T_room_from_phantom, 0.2);
}

}  // namespace lftrack::calib
