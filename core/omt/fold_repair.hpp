// Fold repair of area-preserving maps by a barrier energy that keeps areas (after Garanzha,
// Kaporin, Kudryavtseva, Protais, Ray, Sokolov, "Foldover-free maps in 50 lines of code",
// ACM TOG 2021). The centroids of neighbouring power cells (Alg. 3, step 4) can come out in
// the wrong order on coarse or CAD-like meshes; a Tutte repair removes such folds but pulls
// the region toward a harmonic layout, trading folds for area distortion. Here the free
// vertices instead minimize, per face f with Jacobian J_f against a reference triangle of
// the face's target area,
//     a_f [ theta (det J^2 + 1) + (1 - theta) |J|_F^2 ] / chi(det J, eps),
//     chi(D, eps) = (D + sqrt(eps^2 + D^2)) / 2,
// which for eps -> 0 is infinite on folded faces and least at det J = 1 (area kept) with J
// a rotation (shape kept). eps starts large enough that a folded start has finite energy
// and shrinks with the smallest det J, so the minimizer leaves the folds; once every face
// turns the right way the energy is a barrier and no fold comes back.
#pragma once

#include <Eigen/Core>
#include <array>
#include <functional>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::omt {

struct BarrierFace {
  std::array<int, 3> v;  // indices into the positions, counter-clockwise in the reference
  Eigen::Matrix2d ref_inv;  // inverse of [q1 - q0, q2 - q0] of the reference triangle
  double weight = 0;        // the reference triangle's area
};

/// The reference triangle of a face with 3-D corners a, b, c, scaled to area `area`.
BarrierFace barrier_face(int i, int j, int k, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                         const Eigen::Vector3d& c, double area);

/// Moves the rows of X (points on the unit sphere) with free[row] != 0 to minimize the
/// energy above over `faces`, keeping them on the sphere; theta weighs the area term. Returns
/// the number of `faces` whose chord triangles still do not face outward (0 on success).
int untangle_by_barrier(const std::vector<BarrierFace>& faces, mesh::Vertices& X, const std::vector<char>& free,
                        double theta = 0.9);

/// Repairs the folded faces of a map X of closed genus-0 `m` onto the unit sphere, one
/// cluster at a time: the vertices within 1, 2, 4, 8 or 16 rings of a folded face are
/// untangled against reference triangles of their faces' target areas (m's face areas
/// scaled to the map's). A cluster's repair is kept only if it leaves fewer folds and a mean
/// |log area ratio| (quality::area_log_ratios) no larger than the map's before the repair.
/// Returns the vertices moved; `folded` gets the folds left. `keep_going`, if given, is
/// called before each cluster with (round, folds left); false cancels (Error(kCancelled)).
int repair_sphere_folds_by_barrier(const mesh::TriMesh& m, mesh::Vertices& X, int& folded,
                                   const std::function<bool(int round, int folds)>& keep_going = {});

}  // namespace brenier::omt
