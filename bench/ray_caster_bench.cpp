// Google Benchmark micro-benchmarks of the ray-casting core: one DRR of the built-in phantom per
// renderer and thread count, and single rays. Run: build/bin/lftrack_microbench
// (`lftrack bench drr` is the side-by-side comparison on a scene, with fidelity and peers.)

#include <benchmark/benchmark.h>

#include <array>
#include <memory>
#include <vector>

#include "lftrack/phantom/spine_phantom.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/ray_integrals.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace {

using namespace lftrack;

std::shared_ptr<const tracking::MuVolume> spine_mu() {
  static const auto volume = [] {
    phantom::SpinePhantomOptions o;  // the default scene's grid
    auto p = phantom::make_spine_phantom(o);
    return std::make_shared<const tracking::MuVolume>(tracking::to_attenuation(p->ct));
  }();
  return volume;
}

tracking::XrayView view256() {
  // The default scene's view A, binned to 256 x 256 over the whole detector.
  auto v = tracking::XrayView::isocentric("A", Eigen::Vector3d::Zero(), Eigen::Vector3d(1, -1, 0),
                                          Eigen::Vector3d(0, 0, 1), 1500, 2100, 512, 512, 0.4);
  return v->resampled(0, 0, 512, 512, 256, 256);
}

tracking::Pose centred_pose() {
  tracking::Pose pose = tracking::Pose::Identity();
  pose.translation() = -spine_mu()->geometry.centre_mm();
  return pose;
}

void BM_Drr256(benchmark::State& state, const char* renderer_name) {
  tracking::ThreadPool pool(static_cast<int>(state.range(0)));
  tracking::RendererOptions options;
  options.pool = &pool;
  auto renderer = tracking::make_renderer(renderer_name, spine_mu(), options);
  const tracking::XrayView view = view256();
  tracking::Image<float> out(256, 256);
  const tracking::Pose pose = centred_pose();
  for (auto _ : state) {
    const Status s = (*renderer)->render(pose, view, tracking::PixelWindow::full(256, 256), out.view());
    benchmark::DoNotOptimize(out.pixels().data());
    if (!s.ok()) state.SkipWithError(s.message().c_str());
  }
  state.SetItemsProcessed(state.iterations() * 256 * 256);
  state.counters["threads"] = static_cast<double>(state.range(0));
}
BENCHMARK_CAPTURE(BM_Drr256, siddon, "siddon")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(BM_Drr256, trilinear, "trilinear")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

void BM_SiddonRay(benchmark::State& state) {
  const tracking::GridRayCaster caster(*spine_mu());
  const auto& g = spine_mu()->geometry;
  const Eigen::Vector3d a(-500, 0.4 * g.extent_mm().y(), 0.5 * g.extent_mm().z());
  const Eigen::Vector3d b(g.extent_mm().x() + 500, 0.6 * g.extent_mm().y(), 0.45 * g.extent_mm().z());
  for (auto _ : state) benchmark::DoNotOptimize(caster.siddon(a, b));
}
BENCHMARK(BM_SiddonRay);

// A light-field-precompute-like batch: 256 whole lines from one source point through a row of
// points in the phantom, walked one at a time (Arg 0), in the widest vector lanes the CPU has
// (Arg 1: AVX-512, else AVX2) or in AVX2 lanes (Arg 2).
void BM_SiddonBatch(benchmark::State& state) {
  const auto lanes = std::array{tracking::SiddonLanes::kNone, tracking::SiddonLanes::kBest,
                                tracking::SiddonLanes::kAvx2}[static_cast<std::size_t>(state.range(0))];
  if (lanes != tracking::SiddonLanes::kNone && !tracking::GridRayCaster::siddon_lanes_available(lanes)) {
    state.SkipWithError("no such vector lanes on this CPU");
    return;
  }
  const tracking::GridRayCaster caster(*spine_mu());
  const Eigen::Vector3d extent = spine_mu()->geometry.extent_mm();
  const Eigen::Vector3d source(-1500, 0.5 * extent.y() - 300, 0.5 * extent.z());
  std::vector<Eigen::Vector3d> from(256, source), to(256);
  for (int i = 0; i < 256; ++i) {
    const Eigen::Vector3d target(0.5 * extent.x(), (0.1 + 0.8 * i / 255.0) * extent.y(), 0.45 * extent.z());
    to[static_cast<std::size_t>(i)] = source + 2.0 * (target - source);
  }
  std::vector<double> integrals(256);
  for (auto _ : state) {
    caster.siddon_batch(from, to, integrals, lanes);
    benchmark::DoNotOptimize(integrals.data());
  }
  state.SetItemsProcessed(state.iterations() * 256);
}
BENCHMARK(BM_SiddonBatch)->Arg(0)->Arg(1)->Arg(2)->ArgName("lanes");

}  // namespace

BENCHMARK_MAIN();
