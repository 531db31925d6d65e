// Every renderer, through the factory, on the same fixtures (DESIGN.md test level 2).

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>
#include <thread>

#include "fixtures.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/image_metrics.hpp"
#include "lftrack/tracking/ray_integrals.hpp"
#include "lftrack/tracking/thread_pool.hpp"

// Counts heap allocations in this test binary, to prove render() allocates nothing.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
namespace {
std::atomic<long> g_allocations{0};
}
// Heap allocations so far in this test binary (other test files use it too).
long lftrack_test_allocations() {
  return g_allocations.load();
}
void* operator new(std::size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept {
  std::free(p);
}
void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}
#pragma GCC diagnostic pop

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

using test::fixture_view;
using test::fixture_volume;

// Every renderer by name, the light field once per storage mode.
struct RendererCase {
  std::string name;
  LightFieldStorage storage = LightFieldStorage::kFloat32;
  double octree_pivot = 0;  // octree: 0 is lossless
  std::string label() const {
    if (name == "lightfield") return name + "_" + to_string(storage);
    if (name == "octree")
      return name + "_pivot_permille" + std::to_string(int(std::lround(octree_pivot * 1000)));
    return name;
  }
};

std::vector<RendererCase> every_renderer() {
  std::vector<RendererCase> cases;
  for (const auto& name : renderer_names()) {
    if (name == "octree") {
      cases.push_back({name, LightFieldStorage::kFloat32, 0.0});
      cases.push_back({name, LightFieldStorage::kFloat32, 0.02});
      continue;
    }
    if (name != "lightfield") {
      cases.push_back({name});
      continue;
    }
    for (auto storage : {LightFieldStorage::kFloat32, LightFieldStorage::kFixed16, LightFieldStorage::kVq})
      cases.push_back({name, storage});
  }
  return cases;
}

void PrintTo(const RendererCase& c, std::ostream* os) {
  *os << c.label();
}

Result<std::unique_ptr<DrrRenderer>> make(const RendererCase& c, ThreadPool* pool = nullptr) {
  RendererOptions options;
  options.pool = pool;
  options.octree_pivot = c.octree_pivot;
  if (c.name == "lightfield") options.light_fields = {test::fixture_light_field(c.storage)};
  return make_renderer(c.name, fixture_volume(), options);
}

class EveryRenderer : public ::testing::TestWithParam<RendererCase> {
 protected:
  void SetUp() override {
    volume_ = fixture_volume();
    auto r = make(GetParam());
    ASSERT_TRUE(r.ok()) << r.status().message();
    renderer_ = std::move(r).value();
    view_ = fixture_view();
    pose_ = Pose::Identity();
    pose_.linear() = rotation_exp(Vector3d(0.05, -0.1, 0.15));  // inside the fixture fields' envelope
    pose_.translation() = Vector3d(1.5, -2.0, 0.7);
  }
  Image<float> render(const Pose& pose, const XrayView& view, PixelWindow w, const DrrRenderer& r) {
    Image<float> out(w.rows, w.cols, -1.0f);
    Image<unsigned char> valid(w.rows, w.cols, 7);
    RenderExtras extras;
    extras.valid = valid.view();
    const Status s = r.render(pose, view, w, out.view(), &extras);
    EXPECT_TRUE(s.ok()) << s.message();
    int zeros = 0;
    for (unsigned char v : valid.pixels()) {
      EXPECT_TRUE(v == 0 || v == 1);
      zeros += v == 0;
    }
    EXPECT_EQ(zeros, extras.masked_pixels);
    return out;
  }
  std::shared_ptr<const MuVolume> volume_;
  std::unique_ptr<DrrRenderer> renderer_;
  XrayView view_;
  Pose pose_;
};

TEST_P(EveryRenderer, AgreesWithSiddon) {
  auto siddon = make({"siddon"});
  ASSERT_TRUE(siddon.ok());
  const PixelWindow full = PixelWindow::full(view_.rows, view_.cols);
  const Image<float> ours = render(pose_, view_, full, *renderer_);
  const Image<float> ref = render(pose_, view_, full, **siddon);
  // The fixture has sharp steps that interpolating renderers smooth; their fidelity on real CT is
  // measured by `lftrack bench drr` (BENCHMARKS.md). Siddon against itself is exact.
  const double ncc = normalized_cross_correlation(ref.view(), ours.view());
  if (GetParam().name == "siddon") {
    EXPECT_EQ(ncc, 1.0);
  } else if (GetParam().name == "octree" && GetParam().octree_pivot == 0) {
    EXPECT_GT(ncc, 1.0 - 1e-9) << "a lossless octree is the Siddon renderer";
  } else {
    EXPECT_GT(ncc, 0.99);
    EXPECT_GT(psnr_db(ref.view(), ours.view()), 30.0);
  }
  for (float p : ours.pixels()) ASSERT_TRUE(std::isfinite(p) && p >= 0);
}

// Ray casters only (the lossless octree is one): exact per-pixel values, and views moved against
// the CT (a light field is tied to its view's source position; light_field_test.cpp covers it).
class EveryRayCaster : public EveryRenderer {};

TEST_P(EveryRayCaster, EachPixelIsTheRayFromSourceToPixelCentre) {
  const Image<float> drr = render(pose_, view_, PixelWindow::full(view_.rows, view_.cols), *renderer_);
  const GridRayCaster caster(*volume_);
  const Eigen::Isometry3d T_grid_from_room = volume_->geometry.grid_from_ct() * pose_.inverse();
  for (auto [r, c] : {std::pair{0, 0}, {20, 17}, {47, 39}, {31, 5}}) {
    const Vector3d s = T_grid_from_room * view_.source_mm;
    const Vector3d p = T_grid_from_room * view_.pixel_centre_mm(r, c);
    const double expected =
        GetParam().name == "trilinear" ? caster.trilinear(s, p, 0.5) : caster.siddon(s, p);
    EXPECT_NEAR(drr.at(r, c), expected, 1e-5 * std::max(1.0, expected)) << r << "," << c;
  }
}

TEST_P(EveryRenderer, WindowIsACropOfTheFullDetector) {
  const Image<float> full = render(pose_, view_, PixelWindow::full(view_.rows, view_.cols), *renderer_);
  const PixelWindow w{7, 11, 20, 13};
  const Image<float> part = render(pose_, view_, w, *renderer_);
  for (int r = 0; r < w.rows; ++r)
    for (int c = 0; c < w.cols; ++c) ASSERT_NEAR(part.at(r, c), full.at(w.row0 + r, w.col0 + c), 1e-5);
}

TEST_P(EveryRenderer, ThreadedRenderEqualsSingleThreaded) {
  ThreadPool pool(3);
  auto threaded = make(GetParam(), &pool);
  ASSERT_TRUE(threaded.ok());
  const PixelWindow full = PixelWindow::full(view_.rows, view_.cols);
  EXPECT_EQ(render(pose_, view_, full, **threaded).pixels(), render(pose_, view_, full, *renderer_).pixels());
}

TEST_P(EveryRayCaster, MovingTheCtEqualsMovingTheViewTheOtherWay) {
  const PixelWindow full = PixelWindow::full(view_.rows, view_.cols);
  const Image<float> a = render(pose_, view_, full, *renderer_);
  const Image<float> b = render(Pose::Identity(), view_.transformed(pose_.inverse()), full, *renderer_);
  for (std::size_t i = 0; i < a.pixels().size(); ++i) ASSERT_NEAR(a.pixels()[i], b.pixels()[i], 1e-4);
}

TEST_P(EveryRenderer, RaysThatMissGiveZero) {
  Pose far = Pose::Identity();
  far.translation() = Vector3d(0, 0, 500);  // CT moved out of every ray
  const Image<float> drr = render(far, view_, PixelWindow::full(view_.rows, view_.cols), *renderer_);
  for (float p : drr.pixels()) ASSERT_EQ(p, 0.0f);
}

TEST_P(EveryRenderer, RejectsBadArgumentsAndLeavesOutputUntouched) {
  Image<float> out(view_.rows, view_.cols, -7.0f);
  Pose nan_pose = pose_;
  nan_pose.translation().x() = std::nan("");
  EXPECT_FALSE(
      renderer_->render(nan_pose, view_, PixelWindow::full(view_.rows, view_.cols), out.view()).ok());
  EXPECT_FALSE(renderer_->render(pose_, view_, PixelWindow{40, 0, 10, 10}, out.view()).ok());  // outside
  EXPECT_FALSE(renderer_->render(pose_, view_, PixelWindow{0, 0, 10, 10}, out.view()).ok());   // size
  XrayView bad = view_;
  bad.pitch_col_mm = -1;
  EXPECT_FALSE(renderer_->render(pose_, bad, PixelWindow::full(view_.rows, view_.cols), out.view()).ok());
  for (float p : out.pixels()) ASSERT_EQ(p, -7.0f);
}

TEST_P(EveryRenderer, RenderAllocatesNothing) {
  ThreadPool pool(2);
  auto threaded = make(GetParam(), &pool);
  ASSERT_TRUE(threaded.ok());
  Image<float> out(view_.rows, view_.cols);
  const PixelWindow full = PixelWindow::full(view_.rows, view_.cols);
  ASSERT_TRUE((*threaded)->render(pose_, view_, full, out.view()).ok());  // warm-up
  const long before = g_allocations.load();
  for (int n = 0; n < 5; ++n) ASSERT_TRUE((*threaded)->render(pose_, view_, full, out.view()).ok());
  EXPECT_EQ(g_allocations.load() - before, 0);
}

// Threads that never rendered before (a pool worker that missed the warm-up, the simulator's
// frame thread) render without allocating, two at once: a renderer's scratch is made with it, not
// sized on each thread's first call.
TEST_P(EveryRenderer, RenderFromThreadsThatNeverRenderedAllocatesNothing) {
  ThreadPool pool(2);
  auto threaded = make(GetParam(), &pool);
  ASSERT_TRUE(threaded.ok());
  const PixelWindow full = PixelWindow::full(view_.rows, view_.cols);
  Image<float> out_a(view_.rows, view_.cols), out_b(view_.rows, view_.cols);
  std::atomic<int> go{0};
  std::atomic<int> finished{0};
  std::atomic<int> failed_renders{0};
  const auto renders = [&](Image<float>* out) {
    while (go.load() == 0) std::this_thread::yield();
    for (int n = 0; n < 5; ++n)
      if (!(*threaded)->render(pose_, view_, full, out->view()).ok()) failed_renders.fetch_add(1);
    finished.fetch_add(1);
  };
  std::thread a(renders, &out_a);
  std::thread b(renders, &out_b);
  const long before = g_allocations.load();
  go.store(1);
  while (finished.load() < 2) std::this_thread::yield();
  const long allocations = g_allocations.load() - before;
  a.join();
  b.join();
  EXPECT_EQ(allocations, 0);
  EXPECT_EQ(failed_renders.load(), 0);
  EXPECT_EQ(out_a.pixels(), out_b.pixels());
}

INSTANTIATE_TEST_SUITE_P(Factory, EveryRenderer, ::testing::ValuesIn(every_renderer()),
                         [](const auto& p) { return p.param.label(); });
INSTANTIATE_TEST_SUITE_P(Factory, EveryRayCaster,
                         ::testing::Values(RendererCase{"siddon"}, RendererCase{"trilinear"},
                                           RendererCase{"octree"}),
                         [](const auto& p) { return p.param.label(); });

TEST(RendererFactory, UnknownNameListsTheKnownOnes) {
  auto r = make_renderer("raymarch", fixture_volume());
  EXPECT_FALSE(make_renderer("lightfield", fixture_volume()).ok()) << "no fields given";
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("siddon"), std::string::npos);
}

TEST(RendererFactory, RejectsAVolumeWhoseDataDoesNotMatch) {
  auto v = std::make_shared<MuVolume>(*fixture_volume());
  v->values.pop_back();
  EXPECT_FALSE(make_renderer("siddon", v).ok());
}

}  // namespace
}  // namespace lftrack::tracking
