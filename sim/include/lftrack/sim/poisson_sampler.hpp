#pragma once
// Poisson draws for photon counts, fast enough to expose a detector frame of a few hundred
// thousand pixels inside a 33 ms tracking period (issue 24). std::poisson_distribution sets itself
// up anew for every mean (a log-gamma, a log and a square root per pixel) and then rejects with
// further logs; this sampler draws by Hoermann's transformed rejection with squeeze (PTRS, "The
// transformed rejection method for generating Poisson random variables", 1993, the algorithm
// NumPy uses) for means of 10 and more, and by multiplying uniforms below that. Both are exact:
// the draws follow the Poisson distribution of the mean, not an approximation of it.

#include <cstdint>
#include <random>

namespace lftrack::sim {

// One Poisson draw of mean `mean` (0 <= mean <= 1e9; a mean of 0 gives 0) from `rng`. The same
// generator state gives the same draw.
std::int64_t poisson_draw(double mean, std::mt19937_64& rng);

}  // namespace lftrack::sim
