#pragma once
// Vector quantisation of 16-float vectors (2x2x2x2 light-field tiles): a k-means codebook and a
// fast exact nearest-codeword search. Written here because no Debian library offers a k-means
// with an exact pruned search for millions of 16-D vectors against 65,536 centres.
//
// The search sorts codewords by their mean and scans outwards from the query's mean: since
// |x - c|^2 >= 16 (mean(x) - mean(c))^2, a side is done once that bound passes the best distance.
// On smooth data such as attenuation fields a query touches a few dozen codewords instead of all.

#include <array>
#include <cstdint>
#include <vector>

namespace lftrack::tracking {

class ThreadPool;

using Tile = std::array<float, 16>;

class Codebook {
 public:
  explicit Codebook(std::vector<Tile> codewords);
  int size() const { return static_cast<int>(words_.size()); }
  const Tile& word(int index) const { return words_[static_cast<std::size_t>(index)]; }
  // Index of the nearest codeword (squared Euclidean distance); thread-safe.
  int nearest(const Tile& x, float* distance2 = nullptr) const;

 private:
  std::vector<Tile> words_;
  std::vector<float> sorted_means_;  // means in ascending order
  std::vector<int> sorted_index_;    // codeword index of each sorted mean
};

// Trains `size` codewords on `samples` by k-means (Lloyd, `iterations` rounds, seeded random
// initialisation; an empty cluster is re-seeded with a random sample).
Codebook train_codebook(const std::vector<Tile>& samples, int size, int iterations, std::uint64_t seed,
                        ThreadPool* pool);

}  // namespace lftrack::tracking
