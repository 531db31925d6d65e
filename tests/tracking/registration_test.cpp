// Two-view registration on a coarse spine phantom: frames ray-cast exactly (Siddon) at a gold
// pose, registered with light-field DRRs, so the registering renderer never made the frames.

#include "lftrack/tracking/registration.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <thread>

#include "lftrack/phantom/spine_phantom.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/target_error.hpp"
#include "lftrack/tracking/thread_pool.hpp"

long lftrack_test_allocations();  // drr_renderer_test.cpp counts every operator new

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

// The spine phantom on a coarse 2 mm grid (anatomy, not a periodic texture, so the measures
// have one clear optimum), its target vertebra at the room origin.
struct Phantom {
  std::shared_ptr<const MuVolume> mu;
  Pose nominal = Pose::Identity();
};
const Phantom& phantom() {
  static const Phantom p = [] {
    phantom::SpinePhantomOptions o;
    o.size = {96, 96, 64};
    o.spacing_mm = {2.0, 2.0, 2.0};
    auto ph = phantom::make_spine_phantom(o);
    EXPECT_TRUE(ph.ok());
    Phantom out;
    out.mu = std::make_shared<const MuVolume>(to_attenuation(ph->ct));
    out.nominal.translation() = -ph->vertebral_body_centres_mm[std::size_t(ph->target_vertebra)];
    return out;
  }();
  return p;
}

RegistrationSetup two_view_setup(const std::string& similarity) {
  RegistrationSetup s;
  // Two oblique views 90 degrees apart, 96 x 80 pixels of 0.8 mm.
  const XrayView a = *XrayView::isocentric("A", Vector3d::Zero(), Vector3d(0.7071, -0.7071, 0),
                                           Vector3d(0, 0, 1), 1000, 1400, 80, 96, 0.8);
  const XrayView b = *XrayView::isocentric("B", Vector3d::Zero(), Vector3d(-0.7071, -0.7071, 0),
                                           Vector3d(0, 0, 1), 1000, 1400, 80, 96, 0.8);
  s.views = {{a, PixelWindow::full(a.rows, a.cols), {}}, {b, PixelWindow::full(b.rows, b.cols), {}}};
  s.roi_size_mm = {40, 40, 30};
  s.nominal_T_room_from_ct = phantom().nominal;
  s.similarity = similarity;
  s.similarity_options.histogram_bins = 16;
  return s;
}

// Light fields of the phantom for both views (built once): the registering renderer, while the
// frames are ray-cast (Siddon).
std::shared_ptr<const DrrRenderer> light_field_renderer() {
  static const std::shared_ptr<const DrrRenderer> renderer = [] {
    const RegistrationSetup s = two_view_setup("mi");
    ThreadPool pool(0);
    RendererOptions options;
    for (const RegistrationView& v : s.views) {
      LightFieldPlanInput in;
      in.view_room = v.view;
      in.roi_window = v.window;
      in.nominal_T_room_from_ct = phantom().nominal;
      in.roi_centre_ct_mm = phantom().nominal.inverse() * Vector3d::Zero();
      in.envelope = {6.0, 4.0};
      LightFieldSpec spec;
      spec.resolution = {16, 16, 96, 112};
      auto field = LightField::build(*phantom().mu, in, spec, &pool);
      EXPECT_TRUE(field.ok()) << field.status().message();
      options.light_fields.push_back(*field);
    }
    return std::shared_ptr<const DrrRenderer>(
        std::move(make_renderer("lightfield", nullptr, options)).value());
  }();
  return renderer;
}

struct Frames {
  std::vector<Image<float>> images;
  std::vector<ImageView<const float>> views() const {
    std::vector<ImageView<const float>> v;
    for (const auto& im : images) v.push_back(im.view());
    return v;
  }
};

Frames frames_at(const RegistrationSetup& s, const Pose& gold) {
  auto exact = make_renderer("siddon", phantom().mu);
  Frames f;
  for (const auto& v : s.views) {
    f.images.emplace_back(v.window.rows, v.window.cols);
    EXPECT_TRUE((*exact)->render(gold, v.view, v.window, f.images.back().view()).ok());
  }
  return f;
}

Pose gold_pose() {
  PoseDelta d;
  d.translation_mm = {3.0, -2.0, 1.5};
  d.rotation_rad = {deg_to_rad(2.0), deg_to_rad(-1.0), deg_to_rad(1.5)};
  return apply_delta(phantom().nominal, d, Vector3d::Zero());
}

double tre_mm(const Pose& T, const Pose& gold) {
  TreBox box;
  box.edge_mm = 20;
  box.centre_ct_mm = phantom().nominal.inverse() * Vector3d::Zero();
  return target_registration_error(T, gold, phantom().mu->geometry, box).mean_mm;
}

class RegistrationByMeasure : public ::testing::TestWithParam<std::string> {};

TEST_P(RegistrationByMeasure, TwoViewsConvergeFromAKnownOffset) {
  const RegistrationSetup setup = two_view_setup(GetParam());
  ThreadPool pool(2);
  auto reg = Registration::create(light_field_renderer(), setup, &pool);
  ASSERT_TRUE(reg.ok()) << reg.status().message();
  const Pose gold = gold_pose();
  const Frames f = frames_at(setup, gold);
  ASSERT_TRUE((*reg)->set_frames(f.views(), {}).ok());
  ASSERT_GT(tre_mm(phantom().nominal, gold), 3.0);
  auto result = (*reg)->run(phantom().nominal, *registration_plan("papers"), true);
  ASSERT_TRUE(result.ok()) << result.status().message();
  EXPECT_LT(tre_mm(result->T_room_from_ct, gold), 0.5) << GetParam();
  EXPECT_GT(result->evaluations, 12);
  EXPECT_EQ(result->view_similarity.size(), 2u);
  ASSERT_FALSE(result->trace.empty());
  EXPECT_LE(result->trace.back().evaluations, result->evaluations);
}

INSTANTIATE_TEST_SUITE_P(Registration, RegistrationByMeasure, ::testing::Values("mi", "ncc", "gc"),
                         [](const ::testing::TestParamInfo<std::string>& p) { return p.param; });

TEST(Registration, ParallelAndSerialEvaluationAgree) {
  const RegistrationSetup setup = two_view_setup("mi");
  std::shared_ptr<const DrrRenderer> renderer = light_field_renderer();
  ThreadPool pool(2);
  auto parallel = std::move(Registration::create(renderer, setup, &pool)).value();
  auto serial = std::move(Registration::create(renderer, setup, nullptr)).value();
  const Frames f = frames_at(setup, gold_pose());
  ASSERT_TRUE(parallel->set_frames(f.views(), {}).ok());
  ASSERT_TRUE(serial->set_frames(f.views(), {}).ok());
  const auto a = *parallel->run(phantom().nominal, *registration_plan("warm"));
  const auto b = *serial->run(phantom().nominal, *registration_plan("warm"));
  EXPECT_TRUE(a.T_room_from_ct.isApprox(b.T_room_from_ct, 1e-12));
  EXPECT_EQ(a.evaluations, b.evaluations);
}

class PreparedRunByPlan : public ::testing::TestWithParam<std::string> {};

// warm-robust adds a second measure and high-passed levels, made at prepare_plan().
TEST_P(PreparedRunByPlan, SetFramesAndAPreparedRunAllocateNothing) {
  const RegistrationSetup setup = two_view_setup("mi");
  ThreadPool pool(2);
  auto reg = std::move(Registration::create(light_field_renderer(), setup, &pool)).value();
  const Frames f = frames_at(setup, gold_pose());
  const auto frames = f.views();
  const std::vector<ImageView<const unsigned char>> masks;
  const PreparedPlan plan = std::move(reg->prepare_plan(*registration_plan(GetParam()))).value();
  RegistrationResult result;
  ASSERT_TRUE(reg->set_frames(frames, masks).ok());
  ASSERT_TRUE(reg->run(phantom().nominal, plan, 1e9, &result).ok());  // sizes the result once
  const long before = lftrack_test_allocations();
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(reg->set_frames(frames, masks).ok());
    ASSERT_TRUE(reg->run(phantom().nominal, plan, 1e9, &result).ok());
  }
  EXPECT_EQ(lftrack_test_allocations() - before, 0);
  EXPECT_GT(result.evaluations, 12);
  // Where the time went: one summary per pass, adding up to the run's evaluations and time.
  ASSERT_EQ(result.passes.size(), plan.plan.passes.size());
  int evaluations = 0;
  double pass_ms = 0;
  for (const RegistrationPassSummary& pass : result.passes) {
    EXPECT_GT(pass.evaluations, 0);
    EXPECT_GT(pass.elapsed_ms, 0.0);
    evaluations += pass.evaluations;
    pass_ms += pass.elapsed_ms;
  }
  EXPECT_EQ(evaluations, result.evaluations);
  EXPECT_LE(pass_ms, result.elapsed_ms);
  // The same answer as the allocating entry point.
  const auto again = *reg->run(phantom().nominal, *registration_plan(GetParam()));
  EXPECT_TRUE(again.T_room_from_ct.isApprox(result.T_room_from_ct, 1e-12));
}

INSTANTIATE_TEST_SUITE_P(Registration, PreparedRunByPlan,
                         ::testing::Values("warm", "warm-robust", "warm-robust-fast"),
                         [](const ::testing::TestParamInfo<std::string>& p) {
                           std::string name = p.param;
                           std::replace(name.begin(), name.end(), '-', '_');
                           return name;
                         });

// A smooth trend added to the line integrals (what scatter and moved soft tissue do to a real
// frame) pulls mutual information off the pose; the robust plan's high-passed final pass does not
// see it. Its result still reports the setup's measure (MI), so a gate's thresholds keep their
// meaning.
TEST(Registration, RobustPlanHoldsAgainstASmoothTrendThatPullsMutualInformation) {
  const RegistrationSetup setup = two_view_setup("mi");
  ThreadPool pool(2);
  auto reg = std::move(Registration::create(light_field_renderer(), setup, &pool)).value();
  const Pose gold = gold_pose();
  // A broad bump of 0.3 (line-integral units; the phantom's bone adds about that much) and a ramp
  // of half that across each view.
  Frames f = frames_at(setup, gold);
  for (Image<float>& image : f.images) {
    const double rows = image.rows(), cols = image.cols();
    for (int r = 0; r < image.rows(); ++r)
      for (int c = 0; c < image.cols(); ++c) {
        const double x = c / cols - 0.3, y = r / rows - 0.6;
        image.at(r, c) += static_cast<float>(0.3 * (std::exp(-(x * x + y * y) / 0.3) + 0.5 * c / cols));
      }
  }
  ASSERT_TRUE(reg->set_frames(f.views(), {}).ok());
  const auto plain = *reg->run(phantom().nominal, *registration_plan("quadratic"));
  const auto robust = *reg->run(phantom().nominal, *registration_plan("robust"));
  const double plain_tre = tre_mm(plain.T_room_from_ct, gold), robust_tre = tre_mm(robust.T_room_from_ct, gold);
  EXPECT_LT(robust_tre, 0.2);
  EXPECT_LT(robust_tre, 0.5 * plain_tre) << "MI " << plain_tre << " mm, robust " << robust_tre << " mm";
  ASSERT_EQ(robust.view_similarity.size(), 2u);
  EXPECT_NEAR(-(robust.view_similarity[0] + robust.view_similarity[1]), reg->cost_at(robust.T_room_from_ct), 1e-9);
}

// A sharp structure in the frames that the CT does not hold (an organ edge that moved with
// breathing, a gas pocket), kept by the high-pass because it is sharp: plain NCC's final pass
// pulls the vertebra's edges towards it; robust NCC (rncc, the robust plan's) leaves its pixels
// out once they stand beyond the residual's spread. When written: robust-ncc 1.31 mm, robust
// 0.20 mm.
TEST(Registration, RobustPlanIsNotPulledByASharpStructureTheCtDoesNotHold) {
  const RegistrationSetup setup = two_view_setup("mi");
  ThreadPool pool(2);
  auto reg = std::move(Registration::create(light_field_renderer(), setup, &pool)).value();
  const Pose gold = gold_pose();
  Frames f = frames_at(setup, gold);
  for (Image<float>& image : f.images) {
    float lo = image.at(0, 0), hi = lo;
    for (float v : image.pixels()) lo = std::min(lo, v), hi = std::max(hi, v);
    // A block of a fifth of the view, a little off its centre, as bright as the view's range.
    const int r0 = image.rows() / 2 - image.rows() / 10, c0 = image.cols() / 2 + image.cols() / 20;
    for (int r = r0; r < r0 + image.rows() / 5; ++r)
      for (int c = c0; c < c0 + image.cols() / 5; ++c) image.at(r, c) += hi - lo;
  }
  ASSERT_TRUE(reg->set_frames(f.views(), {}).ok());
  const double ncc_tre = tre_mm(reg->run(phantom().nominal, *registration_plan("robust-ncc"))->T_room_from_ct, gold);
  const double rncc_tre = tre_mm(reg->run(phantom().nominal, *registration_plan("robust"))->T_room_from_ct, gold);
  EXPECT_GT(ncc_tre, 0.8) << "the block no longer pulls plain NCC; the test shows nothing";
  EXPECT_LT(rncc_tre, 0.3) << "robust-ncc " << ncc_tre << " mm";
  EXPECT_LT(rncc_tre, 0.25 * ncc_tre);
}

TEST(Registration, FiducialTermPullsTowardsTheMarker) {
  const RegistrationSetup setup = two_view_setup("mi");
  std::shared_ptr<const DrrRenderer> renderer = light_field_renderer();
  auto reg = std::move(Registration::create(renderer, setup, nullptr)).value();
  const Pose gold = gold_pose();
  const Frames f = frames_at(setup, gold);
  ASSERT_TRUE(reg->set_frames(f.views(), {}).ok());
  FiducialTerm term;
  term.marker_ct_mm = phantom().nominal.inverse() * Vector3d(5, -3, 4);
  term.marker_room_mm = gold * term.marker_ct_mm;
  term.gamma_per_mm = 0.05;
  const double without = reg->cost_at(gold);
  reg->set_fiducial(term);
  EXPECT_NEAR(reg->cost_at(gold), without, 1e-12);  // d = 0 at gold
  const double d_nominal = (phantom().nominal * term.marker_ct_mm - term.marker_room_mm).norm();
  const double with_term = reg->cost_at(phantom().nominal);
  reg->set_fiducial(std::nullopt);
  EXPECT_NEAR(with_term - 0.05 * d_nominal, reg->cost_at(phantom().nominal), 1e-9);
  reg->set_fiducial(term);
  auto result = reg->run(phantom().nominal, *registration_plan("papers"));
  ASSERT_TRUE(result.ok());
  EXPECT_LT(tre_mm(result->T_room_from_ct, gold), 0.5);
  EXPECT_LT(result->fiducial_distance_mm, 0.5);
}

TEST(Registration, StaysInsideTheSearchRegion) {
  RegistrationSetup setup = two_view_setup("mi");
  setup.search_translation_mm = 4;
  setup.search_rotation_deg = 3;
  auto reg = std::move(Registration::create(light_field_renderer(), setup, nullptr)).value();
  const Frames f = frames_at(setup, gold_pose());  // gold: 3 mm, 2 degrees from nominal
  ASSERT_TRUE(reg->set_frames(f.views(), {}).ok());
  PoseDelta far;
  far.translation_mm = {6, 0, 0};
  EXPECT_TRUE(std::isinf(reg->cost_at(apply_delta(phantom().nominal, far, Vector3d::Zero()))));
  EXPECT_TRUE(std::isfinite(reg->cost_at(gold_pose())));
  auto result = reg->run(phantom().nominal, *registration_plan("papers"));
  ASSERT_TRUE(result.ok());
  const Vector6d d = delta_between(phantom().nominal, result->T_room_from_ct, Vector3d::Zero()).as_vector();
  EXPECT_LE(d.head<3>().cwiseAbs().maxCoeff(), 4 + 1e-9);
  EXPECT_LT(tre_mm(result->T_room_from_ct, gold_pose()), 0.5);
}

// The robust plan's first pass moves the translations alone. From a start whose rotation lies
// outside the search region every shift costs +infinity; that pass then finds nothing, and the
// passes after it, which move the rotations too, still run from the start.
TEST(Registration, ARobustPlanFromARotationOutsideTheSearchRegionStillRegisters) {
  RegistrationSetup setup = two_view_setup("mi");
  setup.search_rotation_deg = 3;
  auto reg = std::move(Registration::create(light_field_renderer(), setup, nullptr)).value();
  const Frames f = frames_at(setup, gold_pose());  // gold: 3 mm, 2 degrees from nominal
  ASSERT_TRUE(reg->set_frames(f.views(), {}).ok());
  PoseDelta start_delta;
  start_delta.rotation_rad = {deg_to_rad(3.5), 0, 0};
  const Pose start = apply_delta(phantom().nominal, start_delta, Vector3d::Zero());
  EXPECT_TRUE(std::isinf(reg->cost_at(start)));
  const auto plan = *registration_plan("robust");
  ASSERT_TRUE(plan.passes.front().translations_only);
  auto result = reg->run(start, plan);
  ASSERT_TRUE(result.ok()) << result.status().message();
  ASSERT_EQ(result->passes.size(), plan.passes.size()) << "a pass that found nothing ended the plan";
  EXPECT_EQ(result->passes.front().stop, OptimizerStop::kNonFinite);
  EXPECT_NE(result->stop, OptimizerStop::kNonFinite);
  EXPECT_LT(tre_mm(result->T_room_from_ct, gold_pose()), 0.5);
}

// The light field's renderer, `delay_ms` slower a render (2 ms: an evaluation of two views takes
// 4 ms or more).
// A virtual clock that the renderer below advances by its delay per render, from any thread:
// the budget's decisions are the same on a loaded host as on an idle one.
class RenderClock final : public BudgetClock {
 public:
  double now_ms() const override { return 1e-3 * double(us_.load()); }
  void advance_ms(int ms) { us_ += 1000LL * ms; }

 private:
  std::atomic<long long> us_{0};
};

// Each render takes `delay_ms` on the clock (renders on several threads add up, as on one core).
class SlowRenderer final : public DrrRenderer {
 public:
  SlowRenderer(std::shared_ptr<const DrrRenderer> inner, RenderClock* clock)
      : inner_(std::move(inner)), clock_(clock) {}
  std::string_view name() const override { return "slow"; }
  std::atomic<int> delay_ms{2};

 protected:
  Status do_render(const Pose& T, const XrayView& view, const PixelWindow& window, ImageView<float> out,
                   RenderExtras* extras) const override {
    clock_->advance_ms(delay_ms.load());
    return inner_->render(T, view, window, out, extras);
  }

 private:
  std::shared_ptr<const DrrRenderer> inner_;
  RenderClock* clock_;
};

// Runs `plan` with its own budget on `clock`.
Result<RegistrationResult> run_on(Registration& reg, const RegistrationPlan& plan, const RenderClock& clock) {
  auto prepared = reg.prepare_plan(plan);
  if (!prepared.ok()) return prepared.status();
  RegistrationResult result;
  LFTRACK_RETURN_IF_ERROR(reg.run(phantom().nominal, *prepared, plan.max_ms, &result, &clock));
  return result;
}

// A pass takes its time per evaluation from the earlier passes on its level. The first run of a
// one-pass plan with a 50 ms budget has no such time: after its start it begins the batch of 12
// neighbours and the jump (14 evaluations, 2 renders of 4 ms each: 112 ms). The next run knows
// 8 ms an evaluation, so it begins no batch that would end past 50 ms. Once the renderer is fast
// again, the pass's start point is quicker than that stale time, the batch fits and runs, and the
// pass measures its time anew (without the cap every later run stopped after its start point).
TEST(Registration, APassKnowsItsLevelsTimePerEvaluationFromEarlierRuns) {
  const RegistrationSetup setup = two_view_setup("mi");
  RenderClock clock;
  const auto renderer = std::make_shared<SlowRenderer>(light_field_renderer(), &clock);
  auto reg = std::move(Registration::create(renderer, setup, nullptr)).value();
  const Frames f = frames_at(setup, gold_pose());
  ASSERT_TRUE(reg->set_frames(f.views(), {}).ok());
  RegistrationPlan plan;
  plan.name = "one full-resolution pass";
  plan.passes = {{"quadratic-neighbour", 0.0, 1, 0.25, 0.25, 200, ""}};
  plan.max_ms = 50;
  renderer->delay_ms = 4;
  const auto first = run_on(*reg, plan, clock);
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(first->evaluations, 14);
  EXPECT_GE(first->elapsed_ms, 112.0) << "the renders' time on the run's clock";
  const auto next = run_on(*reg, plan, clock);
  ASSERT_TRUE(next.ok());
  EXPECT_EQ(next->evaluations, 1);
  EXPECT_EQ(next->stop, OptimizerStop::kTimeBudget);
  EXPECT_TRUE(next->T_room_from_ct.matrix().allFinite());
  renderer->delay_ms = 1;
  const auto fast = run_on(*reg, plan, clock);
  ASSERT_TRUE(fast.ok());
  EXPECT_GE(fast->evaluations, 14);  // the batch after the start ran (the pass may travel on)
}

// A prior time per evaluation from a slower spell gives way as soon as a first batch runs faster.
// Renders of 30 ms teach 60 ms an evaluation (two views). At 10 ms a render a 300 ms budget fits
// the start and the batch of 13 (20 + 13 x 20 = 280 ms) by the first batch's own time, where the
// stale 60 ms alone said 20 + 13 x 60 = 800 ms and refused the batch in every later run (nothing
// else measures the time again). At 30 ms the same budget refuses it. (A pool's later batches
// spread over its threads, which the prior's ratio to the first batch accounts for: the
// optimizer's budget tests.)
TEST(Registration, APriorFromASlowerSpellGivesWayWhenTheFirstBatchRunsFaster) {
  const RegistrationSetup setup = two_view_setup("mi");
  RenderClock clock;
  const auto renderer = std::make_shared<SlowRenderer>(light_field_renderer(), &clock);
  ThreadPool pool(8);
  auto reg = std::move(Registration::create(renderer, setup, &pool)).value();
  const Frames f = frames_at(setup, gold_pose());
  ASSERT_TRUE(reg->set_frames(f.views(), {}).ok());
  RegistrationPlan plan;
  plan.name = "one batch at full resolution";
  plan.passes = {{"quadratic-neighbour", 0.0, 1, 0.25, 0.25, 14, ""}};  // the start and one batch of 13
  renderer->delay_ms = 30;
  for (int i = 0; i < 3; ++i) {
    const auto learning = run_on(*reg, plan, clock);
    ASSERT_TRUE(learning.ok());
    ASSERT_EQ(learning->evaluations, 14);
  }
  plan.max_ms = 300;
  const auto slow = run_on(*reg, plan, clock);
  ASSERT_TRUE(slow.ok());
  EXPECT_EQ(slow->evaluations, 1) << "at the learnt speed the batch does not fit";
  renderer->delay_ms = 10;
  const auto faster = run_on(*reg, plan, clock);
  ASSERT_TRUE(faster.ok());
  EXPECT_EQ(faster->evaluations, 14);
  EXPECT_LE(faster->elapsed_ms, 300.0 + 1e-9);
}

// A plan's pass binned past what a small window allows runs at the coarsest binning it does
// allow: warm's 8 x 8 pass would leave a 24 x 28 window 3 x 3 pixels, so it runs at 4 x 4 (6 x 7)
// and the plan registers as on a larger window.
TEST(Registration, APassBinnedPastASmallWindowRunsAtTheCoarsestBinningItAllows) {
  RegistrationSetup setup = two_view_setup("mi");
  for (RegistrationView& v : setup.views) v.window = {28, 34, 24, 28};
  auto reg = std::move(Registration::create(light_field_renderer(), setup, nullptr)).value();
  PoseDelta d;
  d.translation_mm = {0.6, -0.4, 0.3};
  d.rotation_rad = {deg_to_rad(0.3), 0, deg_to_rad(-0.2)};
  const Pose gold = apply_delta(phantom().nominal, d, Vector3d::Zero());
  const Frames f = frames_at(setup, gold);
  ASSERT_TRUE(reg->set_frames(f.views(), {}).ok());
  const auto result = reg->run(phantom().nominal, *registration_plan("warm"));
  ASSERT_TRUE(result.ok()) << result.status().message();
  ASSERT_EQ(result->passes.size(), 3u);
  EXPECT_TRUE(result->T_room_from_ct.matrix().allFinite());
  EXPECT_LT(tre_mm(result->T_room_from_ct, gold), tre_mm(phantom().nominal, gold));
}

TEST(Registration, RefusesMisuse) {
  const RegistrationSetup setup = two_view_setup("mi");
  std::shared_ptr<const DrrRenderer> renderer = light_field_renderer();
  auto reg = std::move(Registration::create(renderer, setup, nullptr)).value();
  EXPECT_FALSE(reg->run(phantom().nominal, *registration_plan("warm")).ok());  // no frames
  Image<float> small(5, 5);
  EXPECT_FALSE(reg->set_frames({small.view(), small.view()}, {}).ok());
  EXPECT_FALSE(reg->set_frames({small.view()}, {}).ok());
  const Frames f = frames_at(setup, phantom().nominal);
  ASSERT_TRUE(reg->set_frames(f.views(), {}).ok());
  Pose bad = phantom().nominal;
  bad.translation().x() = std::nan("");
  EXPECT_FALSE(reg->run(bad, *registration_plan("warm")).ok());
  RegistrationPlan odd = *registration_plan("warm");
  odd.passes[0].blur_sigma_mm = 0.7;  // a level the set-up did not name is made on demand
  EXPECT_TRUE(reg->run(phantom().nominal, odd).ok());
  for (double absurd : {-1.0, std::nan(""), HUGE_VAL, 1e12}) {
    RegistrationPlan blur = *registration_plan("warm"), highpass = blur;
    blur.passes[0].blur_sigma_mm = absurd;
    highpass.passes[1].highpass_sigma_mm = absurd;
    EXPECT_FALSE(reg->run(phantom().nominal, blur).ok()) << absurd;
    EXPECT_FALSE(reg->run(phantom().nominal, highpass).ok()) << absurd;
  }
  RegistrationPlan zero_bin = *registration_plan("warm");
  zero_bin.passes[0].bin = 0;
  EXPECT_FALSE(reg->run(phantom().nominal, zero_bin).ok());
  RegistrationPlan unknown_measure = *registration_plan("robust");
  unknown_measure.passes.back().similarity = "entropy";
  EXPECT_FALSE(reg->run(phantom().nominal, unknown_measure).ok());
  RegistrationResult ignored;
  PreparedPlan tampered = std::move(reg->prepare_plan(*registration_plan("warm"))).value();
  tampered.measures[0] = 99;
  EXPECT_FALSE(reg->run(phantom().nominal, tampered, 1e9, &ignored).ok());
  tampered = std::move(reg->prepare_plan(*registration_plan("warm"))).value();
  tampered.levels[1] = -1;
  EXPECT_FALSE(reg->run(phantom().nominal, tampered, 1e9, &ignored).ok());
  auto other = std::move(Registration::create(renderer, setup, nullptr)).value();
  const PreparedPlan foreign = std::move(other->prepare_plan(*registration_plan("warm"))).value();
  EXPECT_FALSE(reg->run(phantom().nominal, foreign, 1e9, &ignored).ok());  // another registration's indices
  EXPECT_FALSE(registration_plan("fast").ok());
  RegistrationSetup no_views = setup;
  no_views.views.clear();
  EXPECT_FALSE(Registration::create(renderer, no_views, nullptr).ok());
  RegistrationSetup bad_measure = setup;
  bad_measure.similarity = "entropy";
  EXPECT_FALSE(Registration::create(renderer, bad_measure, nullptr).ok());
}

}  // namespace
}  // namespace lftrack::tracking
