// The simulator's detectors (sim_detectors.cpp, issue 51): whole-detector frames, the ROI window
// as before and the rest of the detector coarser, against the exact frame over the whole
// detector (Siddon, every pixel).

#include "lftrack/sim_devices/sim_detectors.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "lftrack/session/scene_registration.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/image_metrics.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::sim_devices {

using session::load_scene;
using session::prepare_scene;
using session::SimDetectorsOptions;

namespace {

TEST(SimDetectors, TheRestOfTheDetectorIsTheExactFrameCoarserAndTheWindowIsUnchanged) {
  tracking::ThreadPool pool(2);
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok());
  scene->sim.renderer = "siddon";
  auto p = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(p.ok()) << p.status().message();
  auto siddon = tracking::make_renderer("siddon", p->world_mu);
  ASSERT_TRUE(siddon.ok());
  const std::shared_ptr<const tracking::DrrRenderer> exact = std::move(siddon).value();
  sim::DetectorModel model = scene_detector_model(*p);
  model.noise = false;
  SimDetectorsOptions whole_options, window_options;
  window_options.whole_detector = false;
  auto whole = SimDetectors::create(*p, exact, nullptr, model, whole_options);
  auto windows = SimDetectors::create(*p, exact, nullptr, model, window_options);
  ASSERT_TRUE(whole.ok() && windows.ok()) << whole.status().message();
  EXPECT_TRUE(whole->whole_detector());
  EXPECT_FALSE(windows->whole_detector());
  auto a = whole->make_frames(), b = windows->make_frames();
  tracking::Pose pose = p->nominal_T_room_from_ct;
  pose.translation() += Eigen::Vector3d(2, -1, 3);
  ASSERT_TRUE(whole->expose(pose, 9, &a).ok());
  ASSERT_TRUE(windows->expose(pose, 9, &b).ok());
  for (std::size_t v = 0; v < a.size(); ++v) {
    const auto& view = p->scene.detectors[v].view;
    const tracking::PixelWindow w = whole->window(v);
    // The reference: every pixel exact.
    sim::FrameSynthesizer all(tracking::PixelWindow::full(view.rows, view.cols), model);
    tracking::Image<std::uint16_t> reference(view.rows, view.cols, 0);
    ASSERT_TRUE(all.synthesize(*exact, pose, view, 9, reference.view()).ok());
    std::vector<float> ours, theirs;
    double ours_sum = 0, theirs_sum = 0;
    for (int r = 0; r < view.rows; ++r)
      for (int c = 0; c < view.cols; ++c) {
        if (w.contains(r, c)) {
          ASSERT_EQ(a[v].at(r, c), b[v].at(r, c)) << "the window as before, view " << view.name;
          continue;
        }
        ASSERT_EQ(b[v].at(r, c), 0) << "without the surround the rest stays unexposed";
        ours.push_back(float(a[v].at(r, c)));
        theirs.push_back(float(reference.at(r, c)));
        ours_sum += ours.back();
        theirs_sum += theirs.back();
      }
    const tracking::ImageView<const float> ov(ours.data(), 1, int(ours.size()), std::ptrdiff_t(ours.size()));
    const tracking::ImageView<const float> tv(theirs.data(), 1, int(theirs.size()),
                                              std::ptrdiff_t(theirs.size()));
    const double ncc = tracking::normalized_cross_correlation(ov, tv);
    std::printf("view %s: surround mean / exact mean %.4f, NCC %.4f\n", view.name.c_str(),
                ours_sum / theirs_sum, ncc);
    EXPECT_NEAR(ours_sum / theirs_sum, 1.0, 0.02) << "the same level, view " << view.name;
    EXPECT_GT(ncc, 0.95) << "the same anatomy, coarser, view " << view.name;
  }
}

// With the clinical preset (spectrum, scatter, lag, the fixed pattern) the window is what it was
// without the rest of the detector, frame after frame (lag included); the rest is exposed; a
// patient made without its surround renderers is refused, not imaged black.
TEST(SimDetectors, ClinicalFramesKeepTheirWindowAndRefuseAPatientWithoutTheRest) {
  tracking::ThreadPool pool(2);
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok());
  auto physics = sim_spec::physics_preset("clinical");
  ASSERT_TRUE(physics.ok());
  scene->sim.physics = *physics;
  scene->sim.renderer = "siddon";
  auto p = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(p.ok()) << p.status().message();
  auto made = make_simulated_patient(*p, p->scene.sim.physics, 1, &pool, &pool, nullptr, true);
  ASSERT_TRUE(made.ok()) << made.status().message();
  const auto patient = std::make_shared<const SimulatedPatient>(std::move(made).value());
  const sim::DetectorModel model = scene_detector_model(*p);
  SimDetectorsOptions window_options;
  window_options.whole_detector = false;
  auto whole = SimDetectors::create(*p, nullptr, patient, model);
  auto windows = SimDetectors::create(*p, nullptr, patient, model, window_options);
  ASSERT_TRUE(whole.ok() && windows.ok()) << whole.status().message();
  auto a = whole->make_frames(), b = windows->make_frames();
  for (std::uint64_t k = 0; k < 2; ++k) {
    tracking::Pose pose = p->nominal_T_room_from_ct;
    pose.translation() += Eigen::Vector3d(1.0 * double(k), 0, 0);
    ASSERT_TRUE(whole->expose(pose, 100 + k, &a).ok());
    ASSERT_TRUE(windows->expose(pose, 100 + k, &b).ok());
    for (std::size_t v = 0; v < a.size(); ++v) {
      const tracking::PixelWindow w = whole->window(v);
      std::int64_t exposed_outside = 0;
      for (int r = 0; r < a[v].rows(); ++r)
        for (int c = 0; c < a[v].cols(); ++c) {
          if (w.contains(r, c)) {
            ASSERT_EQ(a[v].at(r, c), b[v].at(r, c)) << "frame " << k << ", view " << v;
          } else {
            exposed_outside += a[v].at(r, c) > 0 ? 1 : 0;
          }
        }
      EXPECT_GT(exposed_outside, std::int64_t(a[v].rows()) * a[v].cols() / 2) << "view " << v;
    }
  }
  auto bare = make_simulated_patient(*p, p->scene.sim.physics, 1, &pool);
  ASSERT_TRUE(bare.ok());
  auto refused = SimDetectors::create(
      *p, nullptr, std::make_shared<const SimulatedPatient>(std::move(bare).value()), model);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("surround"), std::string::npos) << refused.status().message();
}

}  // namespace
}  // namespace lftrack::sim_devices
