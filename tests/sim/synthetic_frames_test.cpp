#include "lftrack/sim/synthetic_frames.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::sim {

namespace {

using namespace lftrack::tracking;

std::shared_ptr<const MuVolume> slab() {
  auto v = std::make_shared<MuVolume>();
  v->geometry.size = {40, 40, 40};
  v->geometry.origin_mm = {-19.5, -19.5, -19.5};
  v->values.assign(64000, 0.02f);
  return v;
}

XrayView view() {
  return *XrayView::isocentric("A", Eigen::Vector3d::Zero(), Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(0, 0, 1), 500,
                               700, 32, 32, 1.0);
}

TEST(SyntheticFrame, NoiselessFramePreprocessesBackToTheLineIntegrals) {
  auto exact = std::move(make_renderer("siddon", slab())).value();
  DetectorModel model;
  model.noise = false;
  model.blur_sigma_px = 0;
  const XrayView v = view();
  const PixelWindow window{4, 6, 20, 22};
  auto frame = synthesize_frame(*exact, Pose::Identity(), v, window, model, 1);
  ASSERT_TRUE(frame.ok()) << frame.status().message();
  EXPECT_EQ(frame->rows(), 32);
  EXPECT_EQ(frame->at(0, 0), 0);  // outside the window: unexposed
  Image<float> expected(window.rows, window.cols), p(window.rows, window.cols);
  Image<unsigned char> valid(window.rows, window.cols);
  ASSERT_TRUE(exact->render(Pose::Identity(), v, window, expected.view()).ok());
  ASSERT_TRUE(preprocess_frame(frame->view(), detector_correction(model), window, p.view(), valid.view()).ok());
  for (int r = 0; r < window.rows; ++r)
    for (int c = 0; c < window.cols; ++c) {
      ASSERT_EQ(valid.at(r, c), 1);
      // 12-bit quantisation at ~1,600 counts: about 3e-4 in p.
      EXPECT_NEAR(p.at(r, c), expected.at(r, c), 2e-3);
    }
}

TEST(SyntheticFrame, PoissonNoiseAtTheStatedDoseAndRepeatableBySeed) {
  auto exact = std::move(make_renderer("siddon", slab())).value();
  DetectorModel model;
  model.blur_sigma_px = 0;
  model.photons_per_pixel = 2000;
  model.bits = 16;
  const XrayView v = view();
  const PixelWindow window = PixelWindow::full(v.rows, v.cols);
  auto a = synthesize_frame(*exact, Pose::Identity(), v, window, model, 42);
  auto b = synthesize_frame(*exact, Pose::Identity(), v, window, model, 42);
  auto c = synthesize_frame(*exact, Pose::Identity(), v, window, model, 43);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  EXPECT_EQ(a->pixels(), b->pixels());
  EXPECT_NE(a->pixels(), c->pixels());
  // Central pixels see 40 mm of mu 0.02: mean photons 2000 e^-0.8 = 899, relative sd 1/30.
  const double gain = detector_correction(model).open_field_counts / model.photons_per_pixel;
  double sum = 0, sum2 = 0;
  int n = 0;
  for (int r = 12; r < 20; ++r)
    for (int col = 12; col < 20; ++col) {
      const double photons = a->at(r, col) / gain;
      sum += photons;
      sum2 += photons * photons;
      ++n;
    }
  const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
  EXPECT_NEAR(mean, 2000 * std::exp(-0.8), 15);
  EXPECT_NEAR(sd, std::sqrt(2000 * std::exp(-0.8)), 10);
}

TEST(SyntheticFrame, RefusesNonsenseModels) {
  auto exact = std::move(make_renderer("siddon", slab())).value();
  DetectorModel model;
  model.photons_per_pixel = 0;
  EXPECT_FALSE(synthesize_frame(*exact, Pose::Identity(), view(), {0, 0, 4, 4}, model, 1).ok());
  model = {};
  model.bits = 20;
  EXPECT_FALSE(synthesize_frame(*exact, Pose::Identity(), view(), {0, 0, 4, 4}, model, 1).ok());
}

}  // namespace
}  // namespace lftrack::sim
