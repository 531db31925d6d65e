// Light-field DRRs on one core: the ROI window of a real-CT-sized detector (144 x 316 pixels of
// 0.4 mm, SAD 1500, SID 2100), at full resolution and 2 x 2 binned (the warm registration's two
// levels), and a 256 x 256 resampling of it (`bench drr`'s image), each with the portable
// kernel, the AVX2 kernel gathering every sample (as before issue 24), the AVX2 kernel with
// runs, and the source-image path (portable and AVX2), side by side in one run. The field is
// the built-in phantom's at 16 x 16 x 192 x 192 (built once, a few seconds); `lftrack bench drr`
// times the real CT's paper-resolution fields.

#include <benchmark/benchmark.h>

#include <memory>
#include <vector>

#include "lftrack/phantom/spine_phantom.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace {

using namespace lftrack;

struct Setup {
  tracking::XrayView view;
  tracking::PixelWindow window;
  tracking::Pose pose = tracking::Pose::Identity();
  std::shared_ptr<const tracking::LightField> field;
};

const Setup& setup() {
  static const Setup s = [] {
    phantom::SpinePhantomOptions o;
    auto spine = phantom::make_spine_phantom(o);
    const tracking::MuVolume mu = tracking::to_attenuation(spine->ct);
    Setup out;
    out.view = *tracking::XrayView::isocentric("A", Eigen::Vector3d::Zero(), Eigen::Vector3d(1, -1, 0),
                                               Eigen::Vector3d(0, 0, 1), 1500, 2100, 512, 512, 0.4);
    out.window = {184, 98, 144, 316};
    out.pose.translation() = -spine->vertebral_body_centres_mm[std::size_t(spine->target_vertebra)];
    tracking::LightFieldPlanInput in;
    in.view_room = out.view;
    in.roi_window = out.window;
    in.nominal_T_room_from_ct = out.pose;
    in.roi_centre_ct_mm = out.pose.inverse() * Eigen::Vector3d::Zero();
    tracking::LightFieldSpec spec;
    spec.resolution = {16, 16, 192, 192};
    tracking::ThreadPool pool(0);
    out.field = *tracking::LightField::build(mu, in, spec, &pool);
    return out;
  }();
  return s;
}

// Renders the image (0: the window, 1: binned 2 x 2, 2: resampled to 256 x 256) with the kernel
// (0: portable, 1: AVX2 gathers, 2: AVX2 runs, each blending 16 samples at every pixel's ray;
// 3: the source image, portable; 4: the source image, AVX2, the renderer's default) at a pose off
// the nominal one (a tracked patient a little away from the set-up). With `cold_cache`, 48 MiB
// (more than the L3 cache) are written between renders, untimed. turn_deg turns the pose further
// about the view's axis.
void render_light_field_drr(benchmark::State& state, int image, int kernel, bool cold_cache, double turn_deg = 0) {
  const Setup& s = setup();
  tracking::XrayView view = s.view;
  tracking::PixelWindow window = s.window;
  if (image > 0) {
    const int rows = image == 1 ? window.rows / 2 : 256, cols = image == 1 ? window.cols / 2 : 256;
    view = s.view.resampled(window.row0, window.col0, window.rows, window.cols, rows, cols);
    window = tracking::PixelWindow::full(rows, cols);
  }
  tracking::RendererOptions options;
  options.light_fields = {s.field};
  const tracking::SimdLevel kernels[] = {tracking::SimdLevel::kScalar, tracking::SimdLevel::kAvx2Gathers,
                                         tracking::SimdLevel::kAvx2, tracking::SimdLevel::kScalar,
                                         tracking::SimdLevel::kAvx2};
  options.simd = kernels[kernel];
  options.light_field_source_image = kernel >= 3;
  auto renderer = tracking::make_renderer("lightfield", nullptr, options);
  tracking::Image<float> out(window.rows, window.cols);
  tracking::Image<unsigned char> valid(window.rows, window.cols);
  tracking::RenderExtras extras;
  extras.valid = valid.view();
  tracking::PoseDelta d;
  d.translation_mm = {1.2, -0.7, 0.9};
  d.rotation_rad = {0.01, -0.015, 0.008};
  // A turn about the view's axis (from the source through the isocentre, the room's origin)
  // turns the image's pixel rows across the field's (s, t) rows.
  d.rotation_rad += tracking::deg_to_rad(turn_deg) * (-s.view.source_mm).normalized();
  const tracking::Pose pose = tracking::apply_delta(s.pose, d, Eigen::Vector3d::Zero());
  std::vector<unsigned char> evict(cold_cache ? std::size_t(48) << 20 : 0);
  for (auto _ : state) {
    if (cold_cache) {
      state.PauseTiming();
      for (std::size_t i = 0; i < evict.size(); i += 64) evict[i] = static_cast<unsigned char>(evict[i] + 1);
      benchmark::ClobberMemory();
      state.ResumeTiming();
    }
    const Status st = (*renderer)->render(pose, view, window, out.view(), &extras);
    benchmark::DoNotOptimize(out.pixels().data());
    if (!st.ok()) state.SkipWithError(st.message().c_str());
  }
  state.SetItemsProcessed(state.iterations() * window.rows * window.cols);
}

// Arg 0: the image; Arg 1: the kernel (render_light_field_drr). One pose over and over: every
// sample it reads is cached.
void BM_LightFieldDrr(benchmark::State& state) {
  render_light_field_drr(state, int(state.range(0)), int(state.range(1)), false);
}
BENCHMARK(BM_LightFieldDrr)
    ->ArgsProduct({{0, 1, 2}, {0, 1, 2, 3, 4}})
    ->ArgNames({"image", "kernel"})
    ->Unit(benchmark::kMicrosecond);

// The 256 x 256 image at poses turned further about the view's axis (Arg 1, degrees), with the
// AVX2 per-ray kernel with runs or the source image (Arg 0: 2 or 4 as above): how a kernel's cost
// follows the turn, which lays the pixel rows across the field's rows (`bench drr`'s poses turn
// by up to the envelope's rotation about each axis).
void BM_LightFieldDrrTurned(benchmark::State& state) {
  render_light_field_drr(state, 2, int(state.range(0)), false, double(state.range(1)));
}
BENCHMARK(BM_LightFieldDrrTurned)
    ->ArgsProduct({{2, 4}, {0, 1, 2, 4, 8}})
    ->ArgNames({"kernel", "turn_deg"})
    ->Unit(benchmark::kMicrosecond);

// The renderer's default on the 256 x 256 image as a registration meets it after the pose or the
// view changed, with nothing cached (`bench drr`'s first render of each pose and view is like
// this). A fixed count: each render's eviction takes several times the render.
void BM_LightFieldDrrColdCache(benchmark::State& state) { render_light_field_drr(state, 2, 4, true); }
BENCHMARK(BM_LightFieldDrrColdCache)->Iterations(100)->Unit(benchmark::kMicrosecond);
}  // namespace
