#pragma once
// Random vectors drawn in a stated order, so that one seed gives the same values whatever the
// compiler. `Eigen::Vector3d(u(rng), u(rng), u(rng))` leaves the order of the three draws to the
// compiler: gcc evaluates the last argument first, clang the first. The built-in phantom, the
// capture-range study's starts and `calibrate`'s simulated errors therefore differed between a
// gcc build and a clang build (the fuzz and sanitizer builds) of the same seed.
//
// draw3 draws z, then y, then x: gcc's order, so every figure recorded from the gcc build stands.

#include <Eigen/Core>

namespace lftrack::tracking {

template <class Distribution, class Engine>
Eigen::Vector3d draw3(Distribution& distribution, Engine& engine) {
  const double z = distribution(engine);
  const double y = distribution(engine);
  const double x = distribution(engine);
  return {x, y, z};
}

}  // namespace lftrack::tracking
