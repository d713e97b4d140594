// The reference triangles of the barrier energy of fold_repair.hpp (per face with Jacobian J
// against a reference triangle of the face's target area, a [theta (det J^2 + 1) +
// (1 - theta) |J|_F^2] / chi(det J, eps)), shared by the fold repair's L-BFGS untangling
// (fold_repair.cpp) and the area refinement's Newton method (area_refinement.cpp).
// Internal to core/omt.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>

#include "mesh/mesh.hpp"

namespace brenier::omt::detail {

struct BarrierFace {
  std::array<int, 3> v;     // indices into the positions, counter-clockwise in the reference
  Eigen::Matrix2d ref_inv;  // inverse of [q1 - q0, q2 - q0] of the reference triangle
  double weight = 0;        // the reference triangle's area
};

// The reference triangle of a face with 3-D corners a, b, c, scaled to area `area`.
inline BarrierFace barrier_face(int i, int j, int k, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                         const Eigen::Vector3d& c, double area) {
  // The face in its own plane: q0 = 0, q1 on the first axis, q2 above it (counter-clockwise).
  const Eigen::Vector3d e = b - a, g = c - a;
  const double len = e.norm();
  const Eigen::Vector3d u = e / len, n = e.cross(g);
  const Eigen::Vector3d w = n.normalized().cross(u);
  Eigen::Matrix2d Q;
  Q << len, g.dot(u), 0, g.dot(w);
  Q *= std::sqrt(area / (0.5 * n.norm()));  // scaled to the target area
  BarrierFace f;
  f.v = {i, j, k};
  f.ref_inv = Q.inverse();
  f.weight = area;
  return f;
}

// The area refinement's energy of a face (eps = 0) and its derivatives in D = det J and
// T = |J|_F^2:  e(D, T) = w [theta (D + 1/D) + (1 - theta) T / D]  (eTT = 0).
struct RefinementScalars {
  double e, eD, eT, eDD, eDT;
};
inline RefinementScalars refinement_scalars(double w, double theta, double D, double T) {
  const double s = 1 - theta;
  return {w * (theta * (D + 1 / D) + s * T / D), w * (theta * (1 - 1 / (D * D)) - s * T / (D * D)), w * s / D,
          w * (2 * theta / (D * D * D) + 2 * s * T / (D * D * D)), -w * s / (D * D)};
}

}  // namespace brenier::omt::detail
