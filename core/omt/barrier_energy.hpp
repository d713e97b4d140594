// The reference triangles of the barrier energy of fold_repair.hpp (per face with Jacobian J
// against a reference triangle of the face's target area, a [theta (det J^2 + 1) +
// (1 - theta) |J|_F^2] / chi(det J, eps)), shared by the fold repair's L-BFGS untangling
// (fold_repair.cpp), with the test that gives up a stalled one, and the area refinement's
// Newton method (area_refinement.cpp).
// Internal to core/omt.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::omt::detail {

struct BarrierFace {
  std::array<int, 3> v;     // indices into the positions, counter-clockwise in the reference
  Eigen::Matrix2d ref_inv;  // inverse of [q1 - q0, q2 - q0] of the reference triangle
  double weight = 0;        // the reference triangle's area
  double scale = 1;         // the area refinement's reweighted rounds: a factor on the face's term
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

// Whether a barrier untangling (fold_repair.cpp) has stalled, from its deepest fold's det J
// after each round so far (`deepest`) and the barrier's current eps. Its schedule (Garanzha
// et al.'s eps update) runs up to 60 rounds of 400 L-BFGS iterations; a region it cannot
// untangle ran them all, and on the spread starts of crowded sphere maps such regions took
// most of the map's time (man 283 of 332 s, dino 24 of 34 s). Traced over twelve sphere
// meshes, the deepest det J of a region that fails stops rising. One that succeeds either
// rises steadily toward zero, a few percent a round, or sits at a plateau and escapes, with
// eps still above a sixth of |det J| (11 of the 12 successes that had a plateau; the
// twelfth, one of man's 1,341 runs, is given up here). So a run stops when, after at least
// kMinRounds rounds, its deepest det J is negative, rose by less than kRise of its magnitude
// over the last kWindow rounds, and eps is below kSharp |det J|. The caller then tries the
// next, larger region.
inline bool untangling_stalled(const std::vector<double>& deepest, double eps) {
  constexpr int kMinRounds = 10, kWindow = 5;
  constexpr double kRise = 0.05, kSharp = 0.1;
  const int r = static_cast<int>(deepest.size()) - 1;
  if (r < kMinRounds) return false;
  const double now = deepest[r], then = deepest[r - kWindow];
  return now < 0 && now - then < kRise * std::abs(then) && eps < kSharp * std::abs(now);
}

// The step bound of the area refinement on the sphere (area_refinement.cpp, FaceNewton::max_step;
// on the plane the determinant is a quadratic, Smith and Schaefer 2015): the first t in
// (0, limit) at which the face (a, b, c), its corners moved by the tangent steps t da, t db, t dc
// and each put back on the unit sphere, turns over (det(a, b, c) reaches 0), or infinity where
// it does not. Putting a corner back on the sphere scales its row of the determinant by a
// positive number, so the sign is that of det(a + t da, b + t db, c + t dc), a cubic in t,
// written from the edges e1 = b - a, e2 = c - a (no cancellation on small faces) as
// (a + t da) . ((e1 + t de1) x (e2 + t de2)). Between its critical points the cubic is
// monotone, so the first interval whose end is not positive holds the root, which bisection
// finds to 1e-6 relative (the step is cut to 0.9 of it). 0 for a face turned over already.
inline double first_turn_on_sphere(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                                   const Eigen::Vector3d& da, const Eigen::Vector3d& db, const Eigen::Vector3d& dc,
                                   double limit) {
  const Eigen::Vector3d e1 = b - a, e2 = c - a, de1 = db - da, de2 = dc - da;
  const Eigen::Vector3d n = e1.cross(e2), dn = de1.cross(e2) + e1.cross(de2), ddn = de1.cross(de2);
  const double c0 = a.dot(n), c1 = da.dot(n) + a.dot(dn), c2 = da.dot(dn) + a.dot(ddn), c3 = da.dot(ddn);
  auto p = [&](double t) { return c0 + t * (c1 + t * (c2 + t * c3)); };
  if (!(c0 > 0)) return 0;
  double ends[3];  // the critical points in (0, limit), roots of 3 c3 t^2 + 2 c2 t + c1, then limit
  int count = 0;
  auto keep = [&](double r) {
    if (r > 0 && r < limit) ends[count++] = r;
  };
  if (std::abs(c3) > 1e-300) {
    const double disc = 4 * c2 * c2 - 12 * c3 * c1;
    if (disc >= 0) {
      const double sq = std::sqrt(disc);
      double r1 = (-2 * c2 - sq) / (6 * c3), r2 = (-2 * c2 + sq) / (6 * c3);
      if (r1 > r2) std::swap(r1, r2);
      keep(r1);
      keep(r2);
    }
  } else if (std::abs(c2) > 1e-300) {
    keep(-c1 / (2 * c2));
  }
  ends[count++] = limit;
  double lo = 0;
  for (int k = 0; k < count; ++k) {
    if (p(ends[k]) > 0) {
      lo = ends[k];
      continue;
    }
    double hi = ends[k];
    for (int it = 0; it < 60 && hi - lo > 1e-6 * hi; ++it) {
      const double mid = 0.5 * (lo + hi);
      (p(mid) > 0 ? lo : hi) = mid;
    }
    return lo;
  }
  return std::numeric_limits<double>::infinity();
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
