#include <gtest/gtest.h>

#include "lftrack/host/scene.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::host {
namespace {

TEST(PreparedScene, BuiltinPhantomPutsTheTargetOnTheIsocentre) {
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok());
  tracking::ThreadPool pool(2);
  auto p = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(p.ok()) << p.status().message();
  EXPECT_LT(p->registration_origin_room_mm().norm(), 1e-9);
  ASSERT_EQ(p->roi_windows.size(), 2u);
  for (std::size_t i = 0; i < 2; ++i) {
    const auto& w = p->roi_windows[i];
    const auto& v = p->scene.detectors[i].view;
    EXPECT_TRUE(w.inside(v.rows, v.cols));
    // The ROI is a part of the detector, around its centre.
    EXPECT_LT(w.rows, v.rows);
    EXPECT_LT(w.cols, v.cols);
    EXPECT_NEAR(w.row0 + 0.5 * w.rows, 0.5 * v.rows, 0.25 * v.rows);
  }
  EXPECT_EQ(p->mu->values.size(), p->ct->values.size());
}

TEST(PreparedScene, MissingCtFileFailsWithItsPath) {
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok());
  auto p = prepare_scene(*scene, "/nonexistent/ct.nii.gz", nullptr);
  ASSERT_FALSE(p.ok());
  EXPECT_NE(p.status().message().find("/nonexistent/ct.nii.gz"), std::string::npos);
}

TEST(PreparedScene, RealCtSceneResolves) {
  const auto file = std::filesystem::path(LFTRACK_SOURCE_DIR) / "scenes/lumbar-ct.yaml";
  LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
  auto scene = load_scene(file.string());
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  tracking::ThreadPool pool(2);
  auto p = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(p.ok()) << p.status().message();
  EXPECT_EQ(p->ct->geometry.size, Eigen::Vector3i(512, 512, 134));
  for (std::size_t i = 0; i < p->roi_windows.size(); ++i) {
    EXPECT_TRUE(p->roi_windows[i].inside(p->scene.detectors[i].view.rows, p->scene.detectors[i].view.cols));
  }
}

}  // namespace
}  // namespace lftrack::host
