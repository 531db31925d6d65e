// The daily detector check against its calibration (calib/detector_qa.hpp): the same panel on
// another day passes; each drift the loop would get wrong (dark level, noise, a flat field that no
// longer holds, new defective pixels and lines) fails with its reason; frames that cannot be
// judged are refused with the reason.

#include "lftrack/calib/detector_qa.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include "lftrack/sim/panel_frames.hpp"

namespace lftrack::calib {
namespace {

using Frames = std::vector<tracking::Image<std::uint16_t>>;

// A 128 x 96 panel of 12 bits: dark level 41 counts, read noise 2, flood at half full scale,
// with the clinical detector's fixed pattern (smooth and per-pixel gain, stuck pixels, 2 lines).
sim::PanelSpec panel() {
  sim::PanelSpec s;
  s.rows = 96;
  s.cols = 128;
  s.open_field_fraction = 0.5;
  s.photons_per_pixel = 6000;
  sim_spec::DetectorEffectsSpec e;
  e.gain_smooth_rms = 0.005;
  e.gain_pixel_rms = 0.003;
  e.defective_pixel_fraction = 0.001;
  e.defective_lines = 2;
  e.heel_gradient = 0.03;
  e.pattern_seed = 11;
  s.effects = e;
  return s;
}

Frames frames(const sim::PanelSpec& s, bool flood, int n, std::uint64_t seed) {
  auto f = sim::simulate_panel_frames(s, flood, n, seed);
  EXPECT_TRUE(f.ok()) << f.status().message();
  return std::move(f).value();
}

DetectorCalibration baseline() {
  const sim::PanelSpec s = panel();
  DetectorCalibrationOptions rule;
  rule.bits = 12;
  auto c = calibrate_detector(frames(s, false, 16, 1), frames(s, true, 16, 1), rule);
  EXPECT_TRUE(c.ok()) << c.status().message();
  c->detector = "A";
  return std::move(c).value();
}

struct Today {
  Frames dark, flood;
};
Today today() {
  const sim::PanelSpec s = panel();
  return {frames(s, false, 8, 2), frames(s, true, 8, 2)};
}

// Adds `counts(r, c)` to every frame of `f`, clipped to 12 bits.
template <class F>
void add(Frames* f, F counts) {
  for (auto& frame : *f)
    for (int r = 0; r < frame.rows(); ++r)
      for (int c = 0; c < frame.cols(); ++c)
        frame.at(r, c) = std::uint16_t(std::clamp(std::lround(frame.at(r, c) + counts(r, c)), 0L, 4095L));
}

TEST(DetectorQa, TheSamePanelOnAnotherDayPasses) {
  const DetectorCalibration b = baseline();
  ASSERT_GT(b.defects, 0) << "the panel's stuck pixels and lines are in the baseline's map";
  const Today t = today();
  auto q = check_detector_quality(b, t.dark, t.flood, {});
  ASSERT_TRUE(q.ok()) << q.status().message();
  EXPECT_TRUE(q->passed) << q->why << "; " << q->measured;
  EXPECT_LT(std::abs(q->dark_drift_counts), 1.0);
  EXPECT_NEAR(q->noise_ratio, 1.0, 0.1);
  EXPECT_LT(q->nonuniformity, 0.005) << "the flat field still holds: what is left is photon noise";
  EXPECT_EQ(q->blocks, 64);
  EXPECT_EQ(q->new_defects, 0);
  EXPECT_NEAR(q->open_field_ratio, 1.0, 0.01);
  EXPECT_NEAR(q->dark_drift_limit_counts, 0.002 * b.open_field_counts, 1e-9);
}

TEST(DetectorQa, ADarkLevelThatDriftedFails) {
  const DetectorCalibration b = baseline();
  Today t = today();
  // 10 counts on every frame: 0.5 % of the open field (about 2,050 counts), beyond the 0.2 %.
  add(&t.dark, [](int, int) { return 10.0; });
  add(&t.flood, [](int, int) { return 10.0; });
  auto q = check_detector_quality(b, t.dark, t.flood, {});
  ASSERT_TRUE(q.ok()) << q.status().message();
  EXPECT_FALSE(q->passed);
  EXPECT_NEAR(q->dark_drift_counts, 10.0, 1.0);
  EXPECT_NE(q->why.find("dark level drifted"), std::string::npos) << q->why;
  // Downwards too.
  Today down = today();
  add(&down.dark, [](int, int) { return -10.0; });
  add(&down.flood, [](int, int) { return -10.0; });
  auto lower = check_detector_quality(b, down.dark, down.flood, {});
  ASSERT_TRUE(lower.ok());
  EXPECT_FALSE(lower->passed);
  EXPECT_NEAR(lower->dark_drift_counts, -10.0, 1.0);
  // Half of that is within it.
  Today half = today();
  add(&half.dark, [](int, int) { return 3.0; });
  add(&half.flood, [](int, int) { return 3.0; });
  auto within = check_detector_quality(b, half.dark, half.flood, {});
  ASSERT_TRUE(within.ok());
  EXPECT_TRUE(within->passed) << within->why;
}

TEST(DetectorQa, NoisierElectronicsFail) {
  const DetectorCalibration b = baseline();
  Today t = today();
  // Read noise from 2 to about 4.5 counts: the dark frames carry 4 counts more, drawn per frame.
  std::mt19937 rng(3);
  std::normal_distribution<double> extra(0, 4);
  add(&t.dark, [&](int, int) { return extra(rng); });
  auto q = check_detector_quality(b, t.dark, t.flood, {});
  ASSERT_TRUE(q.ok()) << q.status().message();
  EXPECT_FALSE(q->passed);
  EXPECT_GT(q->noise_ratio, 1.5);
  EXPECT_NE(q->why.find("temporal noise"), std::string::npos) << q->why;
}

TEST(DetectorQa, TheNoiseRatioDoesNotDependOnTheFrameCountAndACollapsedNoiseFails) {
  const DetectorCalibration b = baseline();  // 16 frames of each
  const sim::PanelSpec s = panel();
  // Today's 8 frames against 96: a median of per-pixel SDs would read x0.96 (0.954 sigma from 8
  // frames, 0.996 from 96); the root of the mean variance reads 1 within its noise.
  DetectorCalibrationOptions rule;
  rule.bits = 12;
  auto many = calibrate_detector(frames(s, false, 96, 9), frames(s, true, 96, 9), rule);
  ASSERT_TRUE(many.ok()) << many.status().message();
  auto q = check_detector_quality(*many, frames(s, false, 8, 7), frames(s, true, 8, 7), {});
  ASSERT_TRUE(q.ok()) << q.status().message();
  EXPECT_NEAR(q->noise_ratio, 1.0, 0.015) << "8 frames against 96: a variance is unbiased";
  DetectorQaTolerances few;
  few.min_frames = 7;
  EXPECT_FALSE(check_detector_qa_tolerances(few).ok()) << "fewer than 8 flag pixels by their noise alone";

  // Each frame mostly the mean of the day's eight (0.7 of it): a read-out that averages, whose
  // noise is a third of the calibration's. (Frames all equal are refused as a frozen detector.)
  Today t = today();
  for (Frames* f : {&t.dark, &t.flood}) {
    const Frames original = *f;
    for (int r = 0; r < original.front().rows(); ++r)
      for (int c = 0; c < original.front().cols(); ++c) {
        double sum = 0;
        for (const auto& frame : original) sum += frame.at(r, c);
        const double mean = sum / double(original.size());
        for (std::size_t i = 0; i < f->size(); ++i)
          (*f)[i].at(r, c) = std::uint16_t(std::lround(0.7 * mean + 0.3 * original[i].at(r, c)));
      }
  }
  auto collapsed = check_detector_quality(b, t.dark, t.flood, {});
  ASSERT_TRUE(collapsed.ok()) << collapsed.status().message();
  EXPECT_FALSE(collapsed->passed);
  EXPECT_LT(collapsed->noise_ratio, 0.5);
  EXPECT_NE(collapsed->why.find("no longer follows the signal"), std::string::npos) << collapsed->why;
}

TEST(DetectorQa, TheTubesOutputIsReportedNotJudged) {
  const DetectorCalibration b = baseline();
  // The flood's signal 20 % weaker everywhere (the tube's output, not the detector).
  const sim::PanelSpec weaker = [] {
    sim::PanelSpec s = panel();
    s.photons_per_pixel *= 0.8;
    s.open_field_fraction *= 0.8;
    return s;
  }();
  auto q = check_detector_quality(b, frames(weaker, false, 8, 2), frames(weaker, true, 8, 2), {});
  ASSERT_TRUE(q.ok()) << q.status().message();
  EXPECT_TRUE(q->passed) << q->why;
  EXPECT_NEAR(q->open_field_ratio, 0.8, 0.01);
}

TEST(DetectorQa, AGainThatDriftedAcrossThePanelFails) {
  const DetectorCalibration b = baseline();
  Today t = today();
  // The flood's signal (about 2,050 counts) 4 % stronger at the right edge than at the left.
  add(&t.flood, [](int, int c) { return 0.04 * 2050.0 * c / 127.0; });
  auto q = check_detector_quality(b, t.dark, t.flood, {});
  ASSERT_TRUE(q.ok()) << q.status().message();
  EXPECT_FALSE(q->passed);
  EXPECT_GT(q->nonuniformity, 0.03);
  EXPECT_NE(q->why.find("non-uniform"), std::string::npos) << q->why;
}

TEST(DetectorQa, NewDefectivePixelsAndANewLineFail) {
  const DetectorCalibration b = baseline();
  // 1e-4 of 12,288 pixels: one new defect is allowed, three are not.
  Today t = today();
  auto hot = [](int r, int c) {
    return (r == 20 && c == 30) || (r == 50 && c == 70) || (r == 80 && c == 100);
  };
  add(&t.dark, [&](int r, int c) { return hot(r, c) ? 1500.0 : 0.0; });
  add(&t.flood, [&](int r, int c) { return hot(r, c) ? 1500.0 : 0.0; });
  auto q = check_detector_quality(b, t.dark, t.flood, {});
  ASSERT_TRUE(q.ok()) << q.status().message();
  EXPECT_FALSE(q->passed);
  EXPECT_EQ(q->new_defects, 3);
  EXPECT_EQ(q->new_defect_limit, 1);
  EXPECT_NE(q->why.find("3 pixels are defective"), std::string::npos) << q->why;

  // One is within the limit.
  Today one = today();
  add(&one.dark, [](int r, int c) { return r == 20 && c == 30 ? 1500.0 : 0.0; });
  add(&one.flood, [](int r, int c) { return r == 20 && c == 30 ? 1500.0 : 0.0; });
  auto single = check_detector_quality(b, one.dark, one.flood, {});
  ASSERT_TRUE(single.ok());
  EXPECT_EQ(single->new_defects, 1);
  EXPECT_TRUE(single->passed) << single->why;

  // A column whose read-out died: its flood reads the dark level.
  Today line = today();
  constexpr int kColumn = 61;
  for (std::size_t i = 0; i < line.flood.size(); ++i)
    for (int r = 0; r < line.flood[i].rows(); ++r) line.flood[i].at(r, kColumn) = line.dark[i].at(r, kColumn);
  auto l = check_detector_quality(b, line.dark, line.flood, {});
  ASSERT_TRUE(l.ok()) << l.status().message();
  EXPECT_FALSE(l->passed);
  ASSERT_EQ(l->new_lines.size(), 1u) << l->measured;
  EXPECT_EQ(l->new_lines[0], "column 61");
  EXPECT_NE(l->why.find("column 61"), std::string::npos) << l->why;
}

TEST(DetectorQa, FramesThatCannotBeJudgedAreRefusedWithTheReason) {
  const DetectorCalibration b = baseline();
  sim::PanelSpec other = panel();
  other.rows = 64;
  auto wrong = check_detector_quality(b, frames(other, false, 8, 2), frames(other, true, 8, 2), {});
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.status().message().find("128 x 64"), std::string::npos) << wrong.status().message();

  Today t = today();
  Frames frozen(8, t.dark.front());
  auto f = check_detector_quality(b, frozen, t.flood, {});
  ASSERT_FALSE(f.ok());
  EXPECT_NE(f.status().message().find("identical"), std::string::npos) << f.status().message();

  Frames few(t.dark.begin(), t.dark.begin() + 3);
  EXPECT_FALSE(check_detector_quality(b, few, t.flood, {}).ok()) << "fewer than 8 dark frames";

  for (double bad : {0.0, -1.0, std::nan(""), std::numeric_limits<double>::infinity(), 1e12}) {
    DetectorQaTolerances tol;
    tol.max_nonuniformity = bad;
    EXPECT_FALSE(check_detector_quality(b, t.dark, t.flood, tol).ok()) << bad;
    tol = {};
    tol.max_dark_drift_fraction = bad;
    EXPECT_FALSE(check_detector_quality(b, t.dark, t.flood, tol).ok()) << bad;
  }
  DetectorQaTolerances one;
  one.max_noise_ratio = 1;
  EXPECT_FALSE(check_detector_qa_tolerances(one).ok()) << "a ratio of 1 fails every panel by its noise";
  EXPECT_FALSE(check_detector_quality(DetectorCalibration{}, t.dark, t.flood, {}).ok())
      << "an empty baseline";
}

}  // namespace
}  // namespace lftrack::calib
