#include "vector_quantizer.hpp"

#include <algorithm>
#include <limits>
#include <numeric>
#include <random>

#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::tracking {
namespace {

float mean_of(const Tile& t) {
  float s = 0;
  for (float v : t) s += v;
  return s / 16.0f;
}

}  // namespace

Codebook::Codebook(std::vector<Tile> codewords) : words_(std::move(codewords)) {
  std::vector<std::pair<float, int>> order;
  order.reserve(words_.size());
  for (std::size_t i = 0; i < words_.size(); ++i) order.emplace_back(mean_of(words_[i]), static_cast<int>(i));
  std::sort(order.begin(), order.end());
  for (const auto& [m, i] : order) {
    sorted_means_.push_back(m);
    sorted_index_.push_back(i);
  }
}

int Codebook::nearest(const Tile& x, float* distance2) const {
  const float mx = mean_of(x);
  const auto n = static_cast<std::ptrdiff_t>(sorted_means_.size());
  std::ptrdiff_t up = std::lower_bound(sorted_means_.begin(), sorted_means_.end(), mx) - sorted_means_.begin();
  std::ptrdiff_t down = up - 1;
  float best = std::numeric_limits<float>::infinity();
  int best_index = sorted_index_.empty() ? -1 : sorted_index_[0];
  auto try_word = [&](std::ptrdiff_t k) {
    const Tile& c = words_[static_cast<std::size_t>(sorted_index_[static_cast<std::size_t>(k)])];
    float d = 0;
    for (int i = 0; i < 16 && d < best; ++i) {  // partial distance: stop once it cannot win
      const float e = x[static_cast<std::size_t>(i)] - c[static_cast<std::size_t>(i)];
      d += e * e;
    }
    if (d < best) {
      best = d;
      best_index = sorted_index_[static_cast<std::size_t>(k)];
    }
  };
  while (up < n || down >= 0) {
    bool progressed = false;
    if (up < n) {
      const float gap = sorted_means_[static_cast<std::size_t>(up)] - mx;
      if (16.0f * gap * gap < best) {
        try_word(up++);
        progressed = true;
      } else {
        up = n;
      }
    }
    if (down >= 0) {
      const float gap = mx - sorted_means_[static_cast<std::size_t>(down)];
      if (16.0f * gap * gap < best) {
        try_word(down--);
        progressed = true;
      } else {
        down = -1;
      }
    }
    if (!progressed && up >= n && down < 0) break;
  }
  if (distance2) *distance2 = best;
  return best_index;
}

Codebook train_codebook(const std::vector<Tile>& samples, int size, int iterations, std::uint64_t seed,
                        ThreadPool* pool) {
  std::mt19937_64 rng(seed);
  const auto n = static_cast<int>(samples.size());
  size = std::max(1, std::min(size, n));
  std::vector<int> order(static_cast<std::size_t>(n));
  std::iota(order.begin(), order.end(), 0);
  std::shuffle(order.begin(), order.end(), rng);
  std::vector<Tile> words;
  for (int i = 0; i < size; ++i) words.push_back(samples[static_cast<std::size_t>(order[static_cast<std::size_t>(i)])]);

  std::vector<int> assignment(static_cast<std::size_t>(n));
  std::uniform_int_distribution<int> pick(0, n - 1);
  for (int iteration = 0; iteration < iterations; ++iteration) {
    const Codebook book(words);
    auto assign = [&](int begin, int end) {
      for (int i = begin; i < end; ++i) assignment[static_cast<std::size_t>(i)] = book.nearest(samples[static_cast<std::size_t>(i)]);
    };
    if (pool) pool->parallel_for(n, 1024, assign);
    else assign(0, n);
    std::vector<std::array<double, 16>> sums(words.size());
    for (auto& s : sums) s.fill(0.0);
    std::vector<int> counts(words.size(), 0);
    for (int i = 0; i < n; ++i) {
      const auto w = static_cast<std::size_t>(assignment[static_cast<std::size_t>(i)]);
      ++counts[w];
      for (std::size_t d = 0; d < 16; ++d) sums[w][d] += samples[static_cast<std::size_t>(i)][d];
    }
    for (std::size_t w = 0; w < words.size(); ++w) {
      if (counts[w] == 0) {
        words[w] = samples[static_cast<std::size_t>(pick(rng))];
        continue;
      }
      for (std::size_t d = 0; d < 16; ++d) words[w][d] = static_cast<float>(sums[w][d] / counts[w]);
    }
  }
  return Codebook(std::move(words));
}

}  // namespace lftrack::tracking
