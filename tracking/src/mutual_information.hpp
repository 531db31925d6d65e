#pragma once
// Private to the similarity factory: mutual information and its normalised form
// (mutual_information.cpp).

#include <memory>

#include "lftrack/tracking/similarity.hpp"

namespace lftrack::tracking {

// mi (normalised = false) or nmi with `bins` bins per axis (clamped to 2..1024); its per-pixel
// passes in AVX2 lanes where the CPU has them and `vector_lanes` allows (the same scores).
std::unique_ptr<Similarity> make_mutual_information(int bins, bool normalised, bool vector_lanes);

}  // namespace lftrack::tracking
