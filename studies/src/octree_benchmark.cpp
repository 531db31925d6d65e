#include "lftrack/studies/octree_benchmark.hpp"

#include <chrono>
#include <cmath>
#include <random>

#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/image_metrics.hpp"
#include "lftrack/tracking/octree_volume.hpp"
#include "quantile.hpp"

namespace lftrack::studies {
namespace {

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace

std::vector<tracking::XrayView> whole_volume_views(const tracking::VolumeGeometry& g, int size) {
  constexpr double kSourceToCentreMm = 1500, kSourceToDetectorMm = 2500;  // paper 3's set-up
  const Eigen::Vector3d centre = g.centre_mm();
  const double extent = g.extent_mm().maxCoeff();
  const double pitch = 1.1 * extent * (kSourceToDetectorMm / kSourceToCentreMm) / size;
  std::vector<tracking::XrayView> views;
  // Lateral (source at the patient's left, +x in LPS) and anterior-posterior (source in front, -y).
  for (const auto& [name, direction] :
       {std::pair{"lateral", Eigen::Vector3d(1, 0, 0)}, std::pair{"ap", Eigen::Vector3d(0, -1, 0)}}) {
    auto v = tracking::XrayView::isocentric(name, centre, direction, Eigen::Vector3d(0, 0, 1),
                                            kSourceToCentreMm, kSourceToDetectorMm, size, size, pitch);
    if (v.ok()) views.push_back(*v);
  }
  return views;
}

Result<OctreeBenchReport> run_octree_benchmark(const tracking::MuVolume& volume, const std::string& ct_name,
                                               const OctreeBenchOptions& o,
                                               const std::function<void(double)>& progress) {
  if (o.pivots.empty()) return invalid_argument("bench octree: no pivots");
  if (o.size < 8 || o.size > 4096) return out_of_range("bench octree: --size must be in [8, 4096]");
  if (o.poses < 1 || o.repeats < 1) return out_of_range("bench octree: --poses and --repeats must be >= 1");
  OctreeBenchReport report;
  report.ct = ct_name;
  report.voxels = volume.geometry.voxel_count();
  report.volume_bytes = volume.values.size() * sizeof(float);
  report.rows = report.cols = o.size;
  report.poses = o.poses;
  const auto views = whole_volume_views(volume.geometry, o.size);
  if (views.size() != 2) return internal_error("bench octree: cannot place the views");

  // Poses within +-5 mm and +-5 degrees about the CT's centre; the first is the identity.
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> unit(-1, 1);
  std::vector<tracking::Pose> poses{tracking::Pose::Identity()};
  while (int(poses.size()) < o.poses) {
    tracking::Vector6d d;
    for (int a = 0; a < 3; ++a) d(a) = 5 * unit(rng);
    for (int a = 3; a < 6; ++a) d(a) = tracking::deg_to_rad(5 * unit(rng));
    poses.push_back(tracking::apply_delta(tracking::Pose::Identity(), tracking::PoseDelta::from_vector(d),
                                          volume.geometry.centre_mm()));
  }
  const std::size_t images = poses.size() * views.size();
  const double steps = double(images) * (1 + double(o.pivots.size()));
  double done = 0;
  auto tick = [&] {
    done += 1;
    if (progress) progress(done / steps);
  };

  // Renders every pose and view `repeats` times; returns the images and the median time.
  auto render_all = [&](const tracking::DrrRenderer& r,
                        std::vector<tracking::Image<float>>* out) -> Result<double> {
    std::vector<double> ms;
    out->clear();
    for (const tracking::Pose& pose : poses)
      for (const tracking::XrayView& view : views) {
        tracking::Image<float> img(view.rows, view.cols);
        for (int k = 0; k < o.repeats; ++k) {
          const auto t0 = Clock::now();
          LFTRACK_RETURN_IF_ERROR(
              r.render(pose, view, tracking::PixelWindow::full(view.rows, view.cols), img.view()));
          ms.push_back(ms_since(t0));
        }
        out->push_back(std::move(img));
        tick();
      }
    return quantile(ms, 0.5);
  };

  auto shared = std::make_shared<const tracking::MuVolume>(volume);
  auto siddon = tracking::make_renderer("siddon", shared);
  if (!siddon.ok()) return siddon.status();
  std::vector<tracking::Image<float>> reference;
  auto siddon_ms = render_all(**siddon, &reference);
  if (!siddon_ms.ok()) return siddon_ms.status();
  report.siddon_ms_median = *siddon_ms;

  for (double pivot : o.pivots) {
    OctreeBenchRow row;
    row.pivot = pivot;
    const auto t0 = Clock::now();
    auto built = tracking::OctreeVolume::build(volume, pivot);
    if (!built.ok()) return built.status();
    row.build_s = ms_since(t0) / 1000;
    auto tree = std::make_shared<const tracking::OctreeVolume>(std::move(built).value());
    row.threshold_per_mm = tree->threshold_per_mm();
    row.cells = tree->leaf_count();
    row.compression_percent = 100 * tree->cell_reduction();
    row.list_bytes = tree->list_bytes();
    const tracking::MuVolume back = tree->decompress();
    for (std::size_t n = 0; n < back.values.size(); ++n)
      row.max_voxel_error_per_mm =
          std::max(row.max_voxel_error_per_mm, std::abs(double(back.values[n]) - double(volume.values[n])));
    tracking::RendererOptions options;
    options.octree = tree;
    auto renderer = tracking::make_renderer("octree", nullptr, options);
    if (!renderer.ok()) return renderer.status();
    row.render_bytes = (*renderer)->bytes();
    std::vector<tracking::Image<float>> drrs;
    auto ms = render_all(**renderer, &drrs);
    if (!ms.ok()) return ms.status();
    row.ms_median = *ms;
    row.speedup_vs_siddon = report.siddon_ms_median / std::max(row.ms_median, 1e-9);
    row.ncc_min_vs_uncompressed = 1;
    double psnr_sum = 0;
    int psnr_finite = 0;
    for (std::size_t i = 0; i < drrs.size(); ++i) {
      const double ncc = tracking::normalized_cross_correlation(reference[i].view(), drrs[i].view());
      row.ncc_vs_uncompressed += ncc / double(drrs.size());
      row.ncc_min_vs_uncompressed = std::min(row.ncc_min_vs_uncompressed, ncc);
      const double psnr = tracking::psnr_db(reference[i].view(), drrs[i].view());
      if (std::isfinite(psnr)) {
        psnr_sum += psnr;
        ++psnr_finite;
      }
    }
    // Identical images have infinite PSNR; the mean is over the others (infinite if none differ).
    row.psnr_db_vs_uncompressed =
        psnr_finite ? psnr_sum / psnr_finite : std::numeric_limits<double>::infinity();
    report.rows_by_pivot.push_back(row);
  }
  return report;
}

nlohmann::json to_json(const OctreeBenchReport& r) {
  nlohmann::json j;
  j["ct"] = r.ct;
  j["voxels"] = r.voxels;
  j["volume_bytes"] = r.volume_bytes;
  j["drr"] = {{"rows", r.rows}, {"cols", r.cols}, {"poses", r.poses}, {"views", {"lateral", "ap"}}};
  j["siddon_ms_median"] = r.siddon_ms_median;
  j["octrees"] = nlohmann::json::array();
  auto finite_or_null = [](double v) {
    return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
  };
  for (const OctreeBenchRow& row : r.rows_by_pivot) {
    j["octrees"].push_back({{"pivot", row.pivot},
                            {"threshold_per_mm", row.threshold_per_mm},
                            {"cells", row.cells},
                            {"compression_percent", row.compression_percent},
                            {"list_bytes", row.list_bytes},
                            {"render_bytes", row.render_bytes},
                            {"build_s", row.build_s},
                            {"max_voxel_error_per_mm", row.max_voxel_error_per_mm},
                            {"ms_median", row.ms_median},
                            {"speedup_vs_siddon", row.speedup_vs_siddon},
                            {"ncc_vs_uncompressed", row.ncc_vs_uncompressed},
                            {"ncc_min_vs_uncompressed", row.ncc_min_vs_uncompressed},
                            {"psnr_db_vs_uncompressed", finite_or_null(row.psnr_db_vs_uncompressed)}});
  }
  return j;
}

}  // namespace lftrack::studies
