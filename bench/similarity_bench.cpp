// Similarity scoring on an image the size of the real-CT scene's ROI window (144 x 316 pixels):
// the per-evaluation cost of each measure, next to the light-field DRR it scores. Mutual
// information also at the window's 4 x 4 and 8 x 8 binnings (36 x 79, 18 x 39), the warm plan's
// first two passes, where a score's fixed cost (its histogram) outweighs its pixels.

#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/similarity.hpp"

namespace {

using lftrack::tracking::Image;

Image<float> textured(int rows, int cols, double shift) {
  Image<float> im(rows, cols);
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0.f, 0.02f);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
      im.at(r, c) = float(2.0 + std::sin(0.05 * (c + shift)) * std::cos(0.04 * r) + (c + shift > cols / 2 ? 1.0 : 0.0)) +
                    noise(rng);
  return im;
}

void BM_Similarity(benchmark::State& state, const char* name) {
  const int rows = static_cast<int>(state.range(0)), cols = static_cast<int>(state.range(1));
  const Image<float> fixed = textured(rows, cols, 0), moving = textured(rows, cols, 1.5);
  const Image<unsigned char> mask(rows, cols, 1);
  auto s = std::move(lftrack::tracking::make_similarity(name)).value();
  if (!s->prepare(fixed.view(), mask.view()).ok()) state.SkipWithError("prepare failed");
  for (auto _ : state) benchmark::DoNotOptimize(s->score(moving.view(), mask.view()));
  state.SetItemsProcessed(state.iterations() * rows * cols);
}
BENCHMARK_CAPTURE(BM_Similarity, mi, "mi")->Args({144, 316})->Args({36, 79})->Args({18, 39})->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, nmi, "nmi")->Args({144, 316})->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, ncc, "ncc")->Args({144, 316})->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, rncc, "rncc")->Args({144, 316})->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, gc, "gc")->Args({144, 316})->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, pi, "pi")->Args({144, 316})->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, gd, "gd")->Args({144, 316})->Unit(benchmark::kMicrosecond);

// Preparing mutual information for a new fixed image (once per view, level and thread for each
// new pair of frames).
void BM_MiPrepare(benchmark::State& state) {
  const Image<float> fixed = textured(144, 316, 0);
  const Image<unsigned char> mask(144, 316, 1);
  auto s = std::move(lftrack::tracking::make_similarity("mi")).value();
  for (auto _ : state)
    if (!s->prepare(fixed.view(), mask.view()).ok()) state.SkipWithError("prepare failed");
  state.SetItemsProcessed(state.iterations() * 144 * 316);
}
BENCHMARK(BM_MiPrepare)->Unit(benchmark::kMicrosecond);

}  // namespace
