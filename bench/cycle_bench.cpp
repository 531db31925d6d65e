// The cycle's costs around the DRRs and scores:
// - the pool on the registration's jobs: a candidate's two views, each 10-60 us of work, as one
//   parallel_for of two chunks (and a batch of 13 candidates as one of 26). With two threads a
//   job ideally takes one chunk's time; with one, both. The gap to that is what a job costs in
//   wake-ups and hand-overs (ThreadPool's header);
// - a frame to line integrals (preprocess_frame), with and without dark and gain images.

#include <benchmark/benchmark.h>

#include <chrono>
#include <cstdint>
#include <random>

#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace {

// Busy for `us` microseconds: a stand-in for a view's render and score, whose length does not
// depend on the caches the pool's threads share.
void busy_us(double us) {
  const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double, std::micro>(us);
  while (std::chrono::steady_clock::now() < until) {
  }
}

// Args: threads, chunks, microseconds a chunk.
void BM_ThreadPoolJob(benchmark::State& state) {
  lftrack::tracking::ThreadPool pool(static_cast<int>(state.range(0)));
  const int chunks = static_cast<int>(state.range(1));
  const double us = static_cast<double>(state.range(2));
  for (auto _ : state) pool.parallel_for(chunks, 1, [&](int begin, int end) {
      for (int i = begin; i < end; ++i) busy_us(us);
    });
  state.counters["ideal_us"] = us * ((chunks + pool.size() - 1) / pool.size());
}
BENCHMARK(BM_ThreadPoolJob)
    ->ArgNames({"threads", "chunks", "us"})
    ->ArgsProduct({{1, 2}, {2}, {10, 20, 60}})
    ->Args({1, 26, 10})
    ->Args({2, 26, 10})
    ->Unit(benchmark::kMicrosecond)
    ->UseRealTime();

// Args: window rows, cols, dark and gain images (0 or 1). A 12-bit frame of Poisson-like counts.
void BM_PreprocessFrame(benchmark::State& state) {
  using namespace lftrack::tracking;
  const int rows = static_cast<int>(state.range(0)), cols = static_cast<int>(state.range(1));
  Image<std::uint16_t> raw(rows, cols);
  std::mt19937 rng(1);
  std::uniform_int_distribution<int> counts(200, 3900);
  for (auto& v : raw.pixels()) v = static_cast<std::uint16_t>(counts(rng));
  DetectorCorrection correction;
  if (state.range(2) != 0) {
    correction.dark_counts = Image<float>(rows, cols, 40.f);
    correction.gain = Image<float>(rows, cols, 1.02f);
  }
  Image<float> line_integral(rows, cols);
  Image<unsigned char> valid(rows, cols);
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        preprocess_frame(raw.view(), correction, {0, 0, rows, cols}, line_integral.view(), valid.view()).ok());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * rows * cols);
}
BENCHMARK(BM_PreprocessFrame)
    ->ArgNames({"rows", "cols", "corrected"})
    ->Args({144, 316, 0})
    ->Args({144, 316, 1})
    ->Args({512, 512, 0})
    ->Unit(benchmark::kMicrosecond);

}  // namespace
