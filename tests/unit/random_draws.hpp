// Random vectors drawn one coordinate after another. A call such as
// Vector3d(N(rng), N(rng), N(rng)) leaves the order of its three draws unspecified, and gcc and
// clang take them in opposite orders, so the Release (gcc) and sanitizer (clang) builds would
// solve different cases (session 62 found one such test). Tests that draw a random vector
// draw it through these; other multi-draw expressions in the tests use named locals.
#pragma once

#include <Eigen/Core>

namespace brenier::test {

template <class Distribution, class Rng>
Eigen::Vector3d draw3(Distribution& d, Rng& rng) {
  const double a = d(rng);
  const double b = d(rng);
  const double c = d(rng);
  return {a, b, c};
}

template <class Distribution, class Rng>
Eigen::Vector2d draw2(Distribution& d, Rng& rng) {
  const double a = d(rng);
  const double b = d(rng);
  return {a, b};
}

}  // namespace brenier::test
