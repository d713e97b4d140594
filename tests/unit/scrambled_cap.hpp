// An icosphere whose vertices within `radius` of vertex 0 are thrown to random points of a small
// cap around it, on the sphere: a cluster of folds that the fold-repair tests untangle. The two
// offsets along the cap's axes are drawn one after the other (random_draws.hpp), so gcc and
// clang build the same case.
#pragma once

#include <random>
#include <vector>

#include <Eigen/Geometry>

#include "mesh/shapes.hpp"
#include "random_draws.hpp"

namespace brenier::test {

struct ScrambledCap {
  mesh::TriMesh mesh;
  mesh::Vertices map;     // the sphere map with the cap scrambled
  std::vector<int> cap;   // the scrambled vertices, in increasing order
};

// spread: the largest offset along each cap axis before the point is put back on the sphere.
inline ScrambledCap scrambled_icosphere_cap(int subdivisions, unsigned seed, double radius, double spread) {
  ScrambledCap s{mesh::make_icosphere(subdivisions), {}, {}};
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  const Eigen::Vector3d c = s.mesh.V.row(0).transpose();
  const Eigen::Vector3d e1 = c.unitOrthogonal(), e2 = c.cross(e1);
  s.map = s.mesh.V;
  for (int v = 0; v < s.mesh.num_vertices(); ++v)
    if ((s.mesh.V.row(v).transpose() - c).norm() < radius) {
      // The first draw goes along e2: the order gcc took when the tests drew both in one
      // expression, so the figures measured then still describe the case.
      const Eigen::Vector2d t = spread * draw2(u, rng);
      s.map.row(v) = (c + t.y() * e1 + t.x() * e2).normalized().transpose();
      s.cap.push_back(v);
    }
  return s;
}

}  // namespace brenier::test
