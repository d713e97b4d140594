// A last step of registration: g carried toward an isometry of the two surfaces.
//
// Alg. 7 (dissertation sec. 4.3) matches the parameter domains by a harmonic map g held by
// the landmarks. Conformal (or area-preserving) maps of two deformed copies of one surface
// differ by more than the landmarks fix wherever the deformation is not conformal (a twist
// stretches the flanks by a few per cent), and that residue is the registration's error.
// For the near-isometric pairs a shape-analysis user registers, the true correspondence is
// the one that distorts lengths least, so after g every source vertex is moved in the
// target's domain to bring f = phi2^-1 o g o phi1 closer to an isometry, with the landmarks
// held and no face turned over, so that g stays a bijection of the domain.
//
// The distortion is the as-rigid-as-possible energy (Liu et al. 2008) of f itself: a source
// face with edge matrix X in its own plane goes to the triangle of the target surface points
// phi2^-1(g(corners)) (exact: phi2^-1 is linear on each triangle of the target's chart, on
// the sphere on each chord triangle, read where the ray from the centre crosses it), with
// 3-D edge matrix T, and
// costs area |T X^-1 - R|^2, R the nearest matrix with orthonormal columns. A barrier
// beta (s + 1/s - 2) on each face's signed area ratio s (image on the target over its own,
// signed by its orientation in the target's chart) keeps faces from folding. The vertices
// move by Gauss-Newton steps (one sparse Cholesky factorization each), a step halved until
// it lowers the energy; on the disk, boundary vertices slide along the circle, on the sphere
// each vertex moves in its tangent plane and goes back onto the sphere; landmarks do not
// move. It stops when three steps in a row lower the energy by less than the tolerance.
#pragma once

#include <functional>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::registration {

struct IsometricRefineOptions {
  int max_iterations = 100;
  double tolerance = 1e-3;  // a step that lowers the energy by less than this share of where it began is small
  /// Called before each step with the steps taken and the energy; false cancels
  /// (Error(kCancelled)).
  std::function<bool(int step, double energy)> keep_going;
};

struct IsometricRefineResult {
  mesh::Vertices mapped;  // the refined g of every source vertex (z = 0 on the disk, unit vectors on the sphere)
  /// Where each row of `mapped` lies in the target's domain mesh (locate()'s answer, found on
  /// the way), so that the caller need not search again.
  std::vector<mesh::SurfacePoint> located;
  int iterations = 0;         // steps taken
  double energy_before = 0;  // the energy (area-weighted mean per face) at g
  double energy_after = 0;
  bool converged = false;    // the last three steps were small, or the energy is at round-off (else the budget ran out or no step lowered it)
  int shortened_steps = 0;   // steps taken shorter than the model's
};

/// Refines g on the unit disk or the unit sphere. `source` the source surface (3-D), `mapped`
/// g of its vertices in the target's domain (z = 0 on the disk, unit vectors on the sphere),
/// `target` the target surface with `target_domain` its vertices' images (the target's disk or
/// sphere map, a bijection onto the domain's inscribed polyhedron), `fixed` the source
/// vertices that must not move (the landmarks). On the disk, boundary vertices of the source
/// slide along the unit circle when some vertex is fixed, and stay where they are otherwise;
/// on the sphere every other vertex moves in its tangent plane and is put back on the sphere.
/// Faces whose image is turned over at the start (against the orientation most of the area
/// has) have no barrier; every other face keeps its orientation at every step.
IsometricRefineResult refine_isometric(const mesh::TriMesh& source, const mesh::Vertices& mapped,
                                       const mesh::TriMesh& target, const mesh::Vertices& target_domain,
                                       const std::vector<int>& fixed, bool sphere,
                                       const IsometricRefineOptions& options = {});

}  // namespace brenier::registration
