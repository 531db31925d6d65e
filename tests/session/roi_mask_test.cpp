// roi.mask (roi_mask.cpp): the target's neighbourhood projected into each view, and a
// registration that looks only there: what lies outside it, however bright, does not move the
// result. On the shipped DICOM CT with a structure set written here.

#include "lftrack/session/roi_mask.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <memory>
#include <sstream>
#include <tuple>

#include "lftrack/session/commissioning_file.hpp"
#include "lftrack/session/dicom_registration.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "rt_writer.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using sim_devices::scene_detector_model;
using sim_devices::synthesize_scene_frames;
namespace {

namespace fs = std::filesystem;
using Eigen::Vector3d;

// The lumbar CT's vertebral body in two coarse views (test_data.hpp), looked at through roi.mask.
std::string scene_text(const fs::path& rtstruct, double margin_mm) {
  std::ostringstream mask;
  mask << "  mask: {rtstruct: " << rtstruct.string() << ", target: L3 body, margin_mm: " << margin_mm << "}\n";
  return test::lumbar_two_coarse_views_scene(mask.str());
}

class RoiMask : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (!fs::exists(test::pancreas_dicom())) return;
    dir_ = std::make_unique<test::TempDir>();
    auto ct = read_ct_dicom_identity(test::pancreas_dicom());
    ASSERT_TRUE(ct.ok()) << ct.status().message();
    test::RtStructSpec set;
    set.frame_of_reference_uid = ct->frame_of_reference_uid;
    set.series_uid = ct->series_uid;
    set.study_uid = ct->study_uid;
    set.structures = {{1, "L3 body", test::lumbar_ct_vertebral_body()}};
    test::write_rt_structure_set(dir_->path() / "structures.dcm", set);
  }
  static void TearDownTestSuite() { dir_.reset(); }
  void SetUp() override { LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom()); }
  static Result<PreparedScene> prepared(double margin_mm, const std::string& text = "") {
    auto scene = parse_scene(text.empty() ? scene_text(dir_->path() / "structures.dcm", margin_mm) : text,
                             "mask.yaml", dir_->path());
    if (!scene.ok()) return scene.status();
    tracking::ThreadPool pool(2);
    return prepare_scene(*scene, "", &pool);
  }
  static std::unique_ptr<test::TempDir> dir_;
};
std::unique_ptr<test::TempDir> RoiMask::dir_;

std::int64_t count(const tracking::Image<unsigned char>& m) {
  std::int64_t n = 0;
  for (unsigned char b : m.pixels()) n += b != 0;
  return n;
}

TEST_F(RoiMask, TheTargetsProjectionGrownByTheMarginInEachWindow) {
  auto tight = prepared(0);
  ASSERT_TRUE(tight.ok()) << tight.status().message();
  auto wide = prepared(8);
  ASSERT_TRUE(wide.ok()) << wide.status().message();
  ASSERT_EQ(tight->roi_masks.size(), 2u);
  for (std::size_t v = 0; v < 2; ++v) {
    const tracking::Image<unsigned char>& m = tight->roi_masks[v];
    const tracking::PixelWindow& w = tight->roi_windows[v];
    ASSERT_EQ(m.rows(), w.rows);
    ASSERT_EQ(m.cols(), w.cols);
    // The target's centre is looked at; the window's corners, outside an ellipse's projection, are not.
    const auto centre = tight->scene.detectors[v].view.project(tight->nominal_T_room_from_ct * Vector3d(6, 107, 184.91));
    ASSERT_TRUE(centre.has_value());
    EXPECT_EQ(m.at(int(centre->y()) - w.row0, int(centre->x()) - w.col0), 1);
    EXPECT_EQ(m.at(0, 0), 0);
    EXPECT_EQ(m.at(w.rows - 1, w.cols - 1), 0);
    // The ellipse is 36 x 28 mm, seen at 45 degrees and magnified 1.4 on 1.6 mm pixels: about
    // 28 pixels wide; the window (the ROI box, 56 x 48 mm) about 50.
    const double fraction = double(count(m)) / double(m.pixels().size());
    EXPECT_GT(fraction, 0.15) << v;
    EXPECT_LT(fraction, 0.75) << v;
    EXPECT_GT(count(wide->roi_masks[v]), count(m) + 100) << "8 mm more on each side";
  }
  // What the verdict was commissioned on changes with the mask.
  EXPECT_NE(commissioning_fingerprint(*tight).geometry, commissioning_fingerprint(*wide).geometry);
}

TEST_F(RoiMask, WhatLiesOutsideTheMaskDoesNotMoveTheRegistration) {
  auto p = prepared(4);
  ASSERT_TRUE(p.ok()) << p.status().message();
  tracking::ThreadPool pool(2);
  tracking::RendererOptions options;
  options.pool = &pool;
  std::shared_ptr<const tracking::DrrRenderer> exact =
      std::move(tracking::make_renderer("siddon", p->mu, options)).value();
  const tracking::Pose gold = *pose_from_nominal_delta(*p, {1.5, -1, 1, 1, 0.5, -0.5});
  auto raw = synthesize_scene_frames(*p, *exact, gold, 3);
  ASSERT_TRUE(raw.ok()) << raw.status().message();
  auto clean = preprocess_scene_frames(*p, *raw, sim::detector_correction(scene_detector_model(*p)));
  ASSERT_TRUE(clean.ok()) << clean.status().message();
  // A bright object (a moved rib, a clip) over the outer part of each window, outside the mask.
  SceneFrames cluttered = *clean;
  for (std::size_t v = 0; v < 2; ++v) {
    tracking::Image<float>& f = cluttered.line_integral[v];
    for (int r = 0; r < f.rows(); ++r)
      for (int c = 0; c < f.cols(); ++c)
        if (!p->roi_masks[v].at(r, c) && (r + c) % 7 < 3) f.at(r, c) += 6.f;
  }
  const auto registered = [&](const PreparedScene& scene, const SceneFrames& frames) {
    auto reg = make_scene_registration(scene, exact, scene.scene.registration, &pool);
    EXPECT_TRUE(reg.ok()) << reg.status().message();
    EXPECT_TRUE((*reg)->set_frames(frames.frames(), frames.masks()).ok());
    auto result = (*reg)->run(scene.nominal_T_room_from_ct, *tracking::registration_plan("quadratic"));
    EXPECT_TRUE(result.ok()) << result.status().message();
    return result.ok() ? result->T_room_from_ct : tracking::Pose::Identity();
  };
  const auto error_mm = [&](const tracking::Pose& T) { return (T * Vector3d(6, 107, 183) - gold * Vector3d(6, 107, 183)).norm(); };
  const tracking::Pose masked_clean = registered(*p, *clean);
  const tracking::Pose masked_cluttered = registered(*p, cluttered);
  EXPECT_LT(error_mm(masked_clean), 0.5);
  EXPECT_LT((masked_cluttered.translation() - masked_clean.translation()).norm(), 1e-6)
      << "the clutter lies outside the mask: the same pixels, the same result";
  PreparedScene unmasked = *p;
  unmasked.roi_masks.clear();
  const tracking::Pose whole_cluttered = registered(unmasked, cluttered);
  EXPECT_GT((whole_cluttered.translation() - masked_clean.translation()).norm(), 0.05)
      << "without the mask, the clutter is registered too";
}

TEST_F(RoiMask, AMaskThatDoesNotBelongIsRefusedAtLoad) {
  const fs::path set = dir_->path() / "structures.dcm";
  std::string text = scene_text(set, 4);
  auto p = prepared(0, std::string(text).replace(text.find("target: L3 body"), 15, "target: L4 body"));
  ASSERT_FALSE(p.ok());
  EXPECT_NE(p.status().message().find("roi.mask: "), std::string::npos) << p.status().message();
  EXPECT_NE(p.status().message().find("no structure named 'L4 body'"), std::string::npos) << p.status().message();
  for (const auto& [from, to, why] : std::vector<std::tuple<std::string, std::string, std::string>>{
           {"margin_mm: 4", "margin_mm: -1", "in [0, 50] mm"},
           {"margin_mm: 4", "margin_mm: nan", "must be a number"},
           {"margin_mm: 4", "margin: 4", "unknown key 'margin'"},
           {", target: L3 body", "", "roi.mask needs 'target'"}}) {
    auto scene = parse_scene(std::string(text).replace(text.find(from), from.size(), to), "mask.yaml", dir_->path());
    ASSERT_FALSE(scene.ok()) << to;
    EXPECT_NE(scene.status().message().find(why), std::string::npos) << scene.status().message();
  }
  // The NIfTI example has no Frame of Reference to tie the structure set to.
  std::string nifti = text;
  nifti.replace(nifti.find(test::pancreas_dicom().string()), test::pancreas_dicom().string().size(),
                test::totalseg_example().string());
  nifti.replace(nifti.find("[6, 107, 184.91]"), 16, "[0, -148, 281]");
  nifti.replace(nifti.find("[6, 107, 183]"), 13, "[0, -148, 281]");
  auto n = prepared(0, nifti);
  ASSERT_FALSE(n.ok());
  EXPECT_NE(n.status().message().find("roi.mask: the structure set is tied to its CT"), std::string::npos)
      << n.status().message();
}

}  // namespace
}  // namespace lftrack::session
