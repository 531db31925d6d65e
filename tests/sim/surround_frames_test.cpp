// The rest of a simulated detector (surround_frames.cpp): every pixel outside the finely rendered
// window, coarser, at the window's levels; the window's own pixels untouched.

#include "lftrack/sim/surround_frames.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::sim {

using sim_spec::clinical_physics;
using sim_spec::XrayPhysicsSpec;
namespace {

using namespace lftrack::tracking;

// 40 mm of water-like mu along the beam (y), 160 mm across: the shadow covers the detector.
std::shared_ptr<const MuVolume> slab(float mu_per_mm = 0.02f) {
  auto v = std::make_shared<MuVolume>();
  v->geometry.size = {160, 40, 160};
  v->geometry.origin_mm = {-79.5, -19.5, -79.5};
  v->values.assign(std::size_t(v->geometry.voxel_count()), mu_per_mm);
  return v;
}

XrayView view() {
  return *XrayView::isocentric("A", Eigen::Vector3d::Zero(), Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(0, 0, 1), 500,
                               700, 64, 64, 1.0);
}

constexpr std::uint16_t kMark = 7;  // what the window holds before the surround is drawn

TEST(SurroundFrame, FillsEveryPixelOutsideTheWindowAtTheWindowsLevelAndNoneInside) {
  auto exact = std::shared_ptr<const DrrRenderer>(std::move(make_renderer("siddon", slab())).value());
  DetectorModel model;
  model.noise = false;
  model.blur_sigma_px = 0;
  const XrayView v = view();
  const PixelWindow window{16, 20, 32, 24};
  // The reference: the frame synthesizer over the whole detector.
  auto reference = synthesize_frame(*exact, Pose::Identity(), v, PixelWindow::full(64, 64), model, 1);
  ASSERT_TRUE(reference.ok()) << reference.status().message();
  auto surround = SurroundSynthesizer::create(window, model, XrayPhysicsSpec{}, 64, 64, 1.0, 1, 16);
  ASSERT_TRUE(surround.ok()) << surround.status().message();
  EXPECT_EQ((*surround)->coarse_rows(), 16);
  Image<std::uint16_t> frame(64, 64, kMark);
  PatientRenderers renderers;
  renderers.attenuation = exact.get();
  ASSERT_TRUE((*surround)->synthesize(renderers, Pose::Identity(), v, 1, frame.view()).ok());
  for (int r = 0; r < 64; ++r)
    for (int c = 0; c < 64; ++c) {
      if (window.contains(r, c)) {
        ASSERT_EQ(frame.at(r, c), kMark) << r << ", " << c;
      } else {
        // The slab's transmission varies smoothly (obliquity): the coarse grid follows it.
        ASSERT_NEAR(frame.at(r, c), reference->at(r, c), 0.005 * reference->at(r, c)) << r << ", " << c;
      }
    }
}

TEST(SurroundFrame, PhotonNoiseOfThePoissonVarianceRepeatableBySeed) {
  auto exact = std::shared_ptr<const DrrRenderer>(std::move(make_renderer("siddon", slab())).value());
  DetectorModel model;
  model.photons_per_pixel = 2000;
  model.bits = 16;
  const XrayView v = view();
  const PixelWindow window{30, 30, 4, 4};
  auto surround = SurroundSynthesizer::create(window, model, XrayPhysicsSpec{}, 64, 64, 1.0, 1);
  ASSERT_TRUE(surround.ok());
  PatientRenderers renderers;
  renderers.attenuation = exact.get();
  Image<std::uint16_t> a(64, 64), b(64, 64), c(64, 64);
  ASSERT_TRUE((*surround)->synthesize(renderers, Pose::Identity(), v, 42, a.view()).ok());
  ASSERT_TRUE((*surround)->synthesize(renderers, Pose::Identity(), v, 42, b.view()).ok());
  ASSERT_TRUE((*surround)->synthesize(renderers, Pose::Identity(), v, 43, c.view()).ok());
  EXPECT_EQ(a.pixels(), b.pixels());
  EXPECT_NE(a.pixels(), c.pixels());
  // The rows above the window see about 40 mm of mu 0.02: 2000 e^-0.8 = 899 photons, sd 30.
  const double gain = detector_correction(model).open_field_counts / model.photons_per_pixel;
  double sum = 0, sum2 = 0;
  int n = 0;
  for (int r = 0; r < 24; ++r)
    for (int col = 24; col < 40; ++col) {
      const double photons = a.at(r, col) / gain;
      sum += photons;
      sum2 += photons * photons;
      ++n;
    }
  const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
  EXPECT_NEAR(mean, 2000 * std::exp(-0.8), 15);
  EXPECT_NEAR(sd, std::sqrt(2000 * std::exp(-0.8)), 4);
}

TEST(SurroundFrame, ClinicalPhysicsMeetsTheWindowWithoutAStep) {
  // 40 mm of 0.5 g/cm^2 per mm: 20 g/cm^2, the water of a pelvis.
  auto water = std::shared_ptr<const DrrRenderer>(std::move(make_renderer("siddon", slab(0.5f))).value());
  auto bone = std::shared_ptr<const DrrRenderer>(std::move(make_renderer("siddon", slab(0.f))).value());
  DetectorModel model;
  model.noise = false;
  model.bits = 16;
  XrayPhysicsSpec physics = clinical_physics();
  physics.detector->defective_lines = 0;  // a line with its own gain would be a step of its own
  const XrayView v = view();
  const PixelWindow window{16, 16, 32, 32};
  auto fine = FrameSynthesizer::create(window, model, physics, 64, 64, 1.0, 3);
  auto surround = SurroundSynthesizer::create(window, model, physics, 64, 64, 1.0, 3);
  ASSERT_TRUE(fine.ok() && surround.ok());
  PatientRenderers renderers;
  renderers.water = water.get();
  renderers.bone = bone.get();
  Image<std::uint16_t> frame(64, 64, 0);
  ASSERT_TRUE((*fine)->synthesize(renderers, Pose::Identity(), v, 5, frame.view()).ok());
  ASSERT_TRUE((*surround)->synthesize(renderers, Pose::Identity(), v, 5, frame.view()).ok());
  double outside = 0, inside = 0;
  for (int c = 20; c < 44; ++c) {
    outside += frame.at(14, c);
    inside += frame.at(17, c);
  }
  EXPECT_GT(inside, 0);
  EXPECT_NEAR(outside / inside, 1.0, 0.05) << "the same heel, grid, scatter and open-field level";
}

// A window on the detector's edge, a detector taller than wide, two coarse pixels across: every
// pixel outside the window is written, none inside, and the level follows the exact frame.
TEST(SurroundFrame, AWindowOnTheEdgeOfANarrowDetector) {
  auto exact = std::shared_ptr<const DrrRenderer>(std::move(make_renderer("siddon", slab())).value());
  DetectorModel model;
  model.noise = false;
  model.blur_sigma_px = 0;
  const XrayView v = *XrayView::isocentric("A", Eigen::Vector3d::Zero(), Eigen::Vector3d(0, -1, 0),
                                           Eigen::Vector3d(0, 0, 1), 500, 700, 80, 24, 1.0);
  const PixelWindow window{0, 0, 30, 24};  // the top rows, the whole width
  auto reference = synthesize_frame(*exact, Pose::Identity(), v, PixelWindow::full(80, 24), model, 1);
  ASSERT_TRUE(reference.ok());
  auto surround = SurroundSynthesizer::create(window, model, XrayPhysicsSpec{}, 80, 24, 1.0, 1, 7);
  ASSERT_TRUE(surround.ok()) << surround.status().message();
  EXPECT_EQ((*surround)->coarse_cols(), 2) << "at least two across";
  Image<std::uint16_t> frame(80, 24, kMark);
  PatientRenderers renderers;
  renderers.attenuation = exact.get();
  ASSERT_TRUE((*surround)->synthesize(renderers, Pose::Identity(), v, 1, frame.view()).ok());
  for (int r = 0; r < 80; ++r)
    for (int c = 0; c < 24; ++c) {
      if (window.contains(r, c)) {
        ASSERT_EQ(frame.at(r, c), kMark) << r << ", " << c;
      } else {
        ASSERT_NEAR(frame.at(r, c), reference->at(r, c), 0.01 * reference->at(r, c)) << r << ", " << c;
      }
    }
}

TEST(SurroundFrame, RefusesWhatItCannotDraw) {
  DetectorModel model;
  const PixelWindow window{16, 16, 32, 32};
  EXPECT_FALSE(SurroundSynthesizer::create(window, model, XrayPhysicsSpec{}, 40, 40, 1.0, 1).ok())
      << "the window outside the detector";
  EXPECT_FALSE(SurroundSynthesizer::create(window, model, XrayPhysicsSpec{}, 64, 64, 0.0, 1).ok());
  EXPECT_FALSE(SurroundSynthesizer::create(window, model, XrayPhysicsSpec{}, 64, 64, NAN, 1).ok());
  EXPECT_FALSE(SurroundSynthesizer::create(window, model, XrayPhysicsSpec{}, 64, 64, 1.0, 1, 1).ok());
  EXPECT_FALSE(SurroundSynthesizer::create({0, 0, 1, 1}, model, XrayPhysicsSpec{}, 1, 64, 1.0, 1).ok())
      << "a detector one pixel high";
  EXPECT_FALSE(SurroundSynthesizer::create(window, model, XrayPhysicsSpec{}, 64, 64, 4.0, 1, 2).ok())
      << "128 mm coarse pixels";
  DetectorModel bad = model;
  bad.photons_per_pixel = -1;
  EXPECT_FALSE(SurroundSynthesizer::create(window, bad, XrayPhysicsSpec{}, 64, 64, 1.0, 1).ok());
  auto surround = SurroundSynthesizer::create(window, model, clinical_physics(), 64, 64, 1.0, 1);
  ASSERT_TRUE(surround.ok());
  auto exact = std::shared_ptr<const DrrRenderer>(std::move(make_renderer("siddon", slab())).value());
  PatientRenderers attenuation_only;
  attenuation_only.attenuation = exact.get();
  Image<std::uint16_t> frame(64, 64, kMark);
  EXPECT_FALSE((*surround)->synthesize(attenuation_only, Pose::Identity(), view(), 1, frame.view()).ok())
      << "a spectrum needs water and bone";
  Image<std::uint16_t> small(32, 32);
  PatientRenderers both;
  both.water = both.bone = exact.get();
  EXPECT_FALSE((*surround)->synthesize(both, Pose::Identity(), view(), 1, small.view()).ok()) << "wrong frame size";
  for (std::uint16_t p : frame.pixels()) ASSERT_EQ(p, kMark) << "a refusal writes nothing";
}

}  // namespace
}  // namespace lftrack::sim
