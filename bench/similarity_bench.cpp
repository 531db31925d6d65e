// Similarity scoring on an image the size of the real-CT scene's ROI window (144 x 316 pixels):
// the per-evaluation cost of each measure, next to the light-field DRR it scores.

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
  const Image<float> fixed = textured(144, 316, 0), moving = textured(144, 316, 1.5);
  const Image<unsigned char> mask(144, 316, 1);
  auto s = std::move(lftrack::tracking::make_similarity(name)).value();
  if (!s->prepare(fixed.view(), mask.view()).ok()) state.SkipWithError("prepare failed");
  for (auto _ : state) benchmark::DoNotOptimize(s->score(moving.view(), mask.view()));
  state.SetItemsProcessed(state.iterations() * 144 * 316);
}
BENCHMARK_CAPTURE(BM_Similarity, mi, "mi")->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, nmi, "nmi")->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, ncc, "ncc")->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, gc, "gc")->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, pi, "pi")->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Similarity, gd, "gd")->Unit(benchmark::kMicrosecond);

}  // namespace
