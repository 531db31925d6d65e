// Our Siddon DRRs against plastimatch's exact DRRs (an independent implementation), on a small
// asymmetric phantom that pins the geometry mapping, and on the real CT at two orthogonal views
// and an oblique pose.

#include "lftrack/studies/plastimatch_peer.hpp"

#include <gtest/gtest.h>

#include "lftrack/session/scene.hpp"
#include "lftrack/studies/drr_benchmark.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/image_metrics.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "lftrack/tracking/volume_io.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::plastimatch_drr_arguments;
using studies::run_plastimatch_drr;
namespace {

using Eigen::Vector3d;
using tracking::Image;
using tracking::Pose;
using tracking::XrayView;

struct Comparison {
  double ncc = 0;
  double max_rel_diff = 0;  // max |peer - ours| / max(ours)
};

Comparison compare(const tracking::DrrRenderer& renderer, const tracking::MuVolume& mu,
                   const std::filesystem::path& mha, const Pose& T_room_from_ct, const XrayView& view_room,
                   const std::filesystem::path& work) {
  Image<float> ours(view_room.rows, view_room.cols);
  EXPECT_TRUE(renderer
                  .render(T_room_from_ct, view_room,
                          tracking::PixelWindow::full(view_room.rows, view_room.cols), ours.view())
                  .ok());
  auto peer = run_plastimatch_drr(view_room.transformed(T_room_from_ct.inverse()), mha, work);
  EXPECT_TRUE(peer.ok()) << peer.status().message();
  if (!peer.ok()) return {};
  EXPECT_EQ(peer->line_integrals.rows(), ours.rows());
  EXPECT_EQ(peer->line_integrals.cols(), ours.cols());
  Comparison c;
  c.ncc = tracking::normalized_cross_correlation(ours.view(), peer->line_integrals.view());
  double peak = 0, worst = 0;
  for (std::size_t i = 0; i < ours.pixels().size(); ++i) {
    peak = std::max(peak, double(ours.pixels()[i]));
    worst = std::max(worst, double(std::abs(ours.pixels()[i] - peer->line_integrals.pixels()[i])));
  }
  c.max_rel_diff = worst / peak;
  (void)mu;
  return c;
}

// Blobs at distinct places so that any flip, transpose or shift of the mapping shows.
tracking::MuVolume asymmetric_phantom() {
  tracking::MuVolume v;
  v.geometry.size = {40, 36, 30};
  v.geometry.spacing_mm = {1.0, 1.5, 2.0};
  v.geometry.origin_mm = {-20, -25, -30};
  v.values.assign(static_cast<std::size_t>(v.geometry.voxel_count()), 0.0f);
  for (int k = 0; k < 30; ++k)
    for (int j = 0; j < 36; ++j)
      for (int i = 0; i < 40; ++i) {
        const Vector3d p = v.geometry.ct_from_index() * Vector3d(i, j, k);
        float mu = (p - Vector3d(8, -5, 10)).norm() < 6 ? 0.05f : 0.0f;
        if ((p - Vector3d(-9, 4, -12)).norm() < 4) mu += 0.08f;
        if (std::abs(p.x() + 2) < 3 && std::abs(p.z() - 18) < 5) mu += 0.03f;
        v.at(i, j, k) = mu;  // zero on the boundary: see ClipsAtTheOuterVoxelCentres
      }
  return v;
}

TEST(PlastimatchPeer, GeometryMappingOnAnAsymmetricPhantom) {
  LFTRACK_REQUIRE_PLASTIMATCH();
  test::TempDir dir;
  const auto mu = std::make_shared<const tracking::MuVolume>(asymmetric_phantom());
  const auto mha = dir.path() / "mu.mha";
  ASSERT_TRUE(tracking::write_metaimage(*mu, mha).ok());
  auto renderer = tracking::make_renderer("siddon", mu);
  ASSERT_TRUE(renderer.ok());
  // Non-square detector, non-square pixels, principal point away from the centre.
  const XrayView full = *XrayView::isocentric("A", Vector3d(2, 1, -3), Vector3d(0.3, -1, 0.2),
                                              Vector3d(0, 0.1, 1), 500, 800, 120, 90, 0.5);
  const XrayView view = full.resampled(10, 5, 100, 80, 70, 40);
  Pose pose = Pose::Identity();
  pose.linear() = tracking::rotation_exp(Vector3d(0.2, -0.1, 0.3));
  pose.translation() = Vector3d(1.5, -2.5, 3.0);
  const Comparison c = compare(**renderer, *mu, mha, pose, view, dir.path() / "out");
  EXPECT_GT(c.ncc, 0.9999);
  EXPECT_LT(c.max_rel_diff, 0.01);
  // The mapping is not trivially satisfied: a mirrored image must correlate much worse.
  auto peer = run_plastimatch_drr(view.transformed(pose.inverse()), mha, dir.path() / "out2");
  ASSERT_TRUE(peer.ok());
  Image<float> mirrored = peer->line_integrals;
  for (int r = 0; r < mirrored.rows(); ++r)
    for (int col = 0; col < mirrored.cols(); ++col)
      mirrored.at(r, col) = peer->line_integrals.at(r, mirrored.cols() - 1 - col);
  Image<float> ours(view.rows, view.cols);
  ASSERT_TRUE(
      (*renderer)->render(pose, view, tracking::PixelWindow::full(view.rows, view.cols), ours.view()).ok());
  EXPECT_LT(tracking::normalized_cross_correlation(ours.view(), mirrored.view()), 0.95);
}

// The real CT, the scene's two orthogonal views binned to 256 x 256 over the whole detector, at
// the nominal pose and at an oblique pose (8 mm, 5 degrees about an oblique axis).
TEST(PlastimatchPeerRealData, AgreesOnTheRealCtAtTwoViewsAndAnObliquePose) {
  LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
  LFTRACK_REQUIRE_PLASTIMATCH();
  auto scene = load_scene((std::filesystem::path(LFTRACK_SOURCE_DIR) / "scenes/lumbar-ct.yaml").string());
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  tracking::ThreadPool pool(2);
  auto p = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(p.ok()) << p.status().message();
  test::TempDir dir;
  const auto mha = dir.path() / "mu.mha";
  ASSERT_TRUE(tracking::write_metaimage(*p->mu, mha).ok());
  tracking::RendererOptions options;
  options.pool = &pool;
  auto renderer = tracking::make_renderer("siddon", p->mu, options);
  ASSERT_TRUE(renderer.ok());

  tracking::PoseDelta oblique;
  oblique.translation_mm = Vector3d(5, -4, 4.8);
  oblique.rotation_rad = tracking::deg_to_rad(5.0) * Vector3d(1, 2, -1).normalized();
  const Pose poses[] = {p->nominal_T_room_from_ct, tracking::apply_delta(p->nominal_T_room_from_ct, oblique,
                                                                         p->registration_origin_room_mm())};
  for (int pose_index = 0; pose_index < 2; ++pose_index) {
    const Pose& pose = poses[pose_index];
    for (const auto& d : p->scene.detectors) {
      const XrayView view = d.view.resampled(0, 0, d.view.rows, d.view.cols, 256, 256);
      const Comparison c = compare(**renderer, *p->mu, mha, pose, view,
                                   dir.path() / ("out_" + d.view.name + std::to_string(pose_index)));
      EXPECT_GE(c.ncc, 0.999) << "view " << d.view.name;
      EXPECT_LT(c.max_rel_diff, 0.01) << "view " << d.view.name;
      std::printf("[ figures  ] view %s, %s pose: NCC %.7f, max |diff| %.2e of peak\n", d.view.name.c_str(),
                  pose_index == 0 ? "nominal" : "oblique", c.ncc, c.max_rel_diff);
    }
  }
}

// The one convention in which plastimatch differs: it integrates over the box spanned by the
// outermost voxel centres, lftrack (DESIGN.md) over the voxels' full extent. A ray through a
// uniform volume of n voxels therefore gets (n - 1) voxels' worth from plastimatch and n from us.
// This matters only where the volume's boundary voxels are not air.
TEST(PlastimatchPeer, ClipsAtTheOuterVoxelCentres) {
  LFTRACK_REQUIRE_PLASTIMATCH();
  test::TempDir dir;
  auto ones = std::make_shared<tracking::MuVolume>();
  ones->geometry.size = {21, 21, 21};
  ones->geometry.origin_mm = {-10, -10, -10};
  ones->values.assign(21 * 21 * 21, 1.0f);
  const auto mha = dir.path() / "ones.mha";
  ASSERT_TRUE(tracking::write_metaimage(*ones, mha).ok());
  const XrayView view = *XrayView::isocentric("A", Vector3d::Zero(), Vector3d(0, -1, 0), Vector3d(0, 0, 1),
                                              1000, 2000, 3, 3, 1.0);
  auto peer = run_plastimatch_drr(view, mha, dir.path() / "out");
  ASSERT_TRUE(peer.ok()) << peer.status().message();
  auto renderer = tracking::make_renderer("siddon", ones);
  ASSERT_TRUE(renderer.ok());
  Image<float> ours(3, 3);
  ASSERT_TRUE(
      (*renderer)->render(Pose::Identity(), view, tracking::PixelWindow::full(3, 3), ours.view()).ok());
  EXPECT_NEAR(ours.at(1, 1), 21.0, 1e-4);
  EXPECT_NEAR(peer->line_integrals.at(1, 1), 20.0, 1e-3);
}

TEST(PlastimatchPeer, MirroredViewsAreRefused) {
  XrayView v = *XrayView::isocentric("A", Vector3d::Zero(), Vector3d(0, -1, 0), Vector3d(0, 0, 1), 500, 800,
                                     10, 10, 1);
  v.pixel00_mm += 9 * v.col_axis;
  v.col_axis = -v.col_axis;
  EXPECT_FALSE(plastimatch_drr_arguments(v, "x.mha", "out").ok());
}

}  // namespace
}  // namespace lftrack::session
