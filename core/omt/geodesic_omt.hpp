// Riemannian optimal mass transport on a triangulated surface (dissertation sec. 3.2.6,
// Alg. 4): the surface's area measure (times an optional density) carried onto point masses
// on the surface with the squared geodesic cost, by the geodesic power diagram
//   W_i(h) = {x on M : d_g(x, p_i)^2 - h_i <= d_g(x, p_j)^2 - h_j for all j}.
//
// Discretization. The mesh is midpoint-subdivided until the cells are resolved (Alg. 4's
// first line); d_g(., p_i)^2 is known at the vertices (geodesics.hpp: heat method or exact)
// and interpolated linearly on each face. Then every W_i ∩ T is a convex polygon cut by
// straight lines, integrated exactly; on a flat patch with exact distances this is the
// planar power diagram itself, since d_i^2 - d_j^2 is affine there.
//
// Heights. Alg. 4 as printed takes the argmin of d^2 + h_k and updates h_i += delta (nu_i -
// w_i): with that sign a cell short of mass would shrink further. Here the power distance is
// d^2 - h, under which raising h_i grows W_i and the update direction is right; and instead
// of the fixed-step ascent, Newton's method on the same concave Kantorovich functional
//   F(h) = int_M min_i (d_i^2 - h_i) dmu + sum_i h_i nu_i,   grad F = nu - mu(W(h)),
// whose Hessian is minus the weighted graph Laplacian of the cells' common sides,
//   -dm_i/dh_j = int_{W_i ∩ W_j} rho / |grad(d_i^2 - d_j^2)| ds  (i != j),
// with Kitagawa-Merigot-Thibert damping (every cell keeps a share of its mass). The start is
// the chordal transport's heights (the squared Euclidean cost on the same surface,
// surface_cells.hpp), scaled toward the Voronoi diagram where it would leave a geodesic cell
// empty.
//
// Storage. Each site keeps its distances only within a radius R_i of it (a few cells);
// a face's candidate sites are those kept at all three of its corners. The radii are
// certified at every evaluation: a site j missing at some corner of face T is at least
// R_j - diam(T) from every point of T, so it cannot win on T while the lower envelope of
// T's candidates stays below (R_j - diam T)^2 - h_j; where that fails the radii grow and
// the distances are recomputed. At each evaluation every vertex first sorts out the few
// sites that can matter on its faces (power distance below a bound of its faces' lower
// envelopes), so a face reads those, not every site kept at its corners; the cells are the
// same either way.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "mesh/mesh.hpp"
#include "omt/omt.hpp"

namespace brenier::omt {

enum class GeodesicMethod { kHeat, kExact };

struct GeodesicOmtOptions {
  double tolerance = 1e-6;  // max relative cell-mass error
  int max_iterations = 100;
  /// Midpoint subdivisions of the mesh; -1: the fewest that give at least `faces_per_cell`
  /// faces per site (at most 4 levels and 4M faces).
  int subdivisions = -1;
  int faces_per_cell = 64;
  GeodesicMethod geodesics = GeodesicMethod::kHeat;
  Progress progress;  // after every Newton iteration
};

struct GeodesicOmtResult {
  mesh::TriMesh mesh;  // the mesh the cells are resolved on: the input, subdivided
  int subdivisions = 0;
  std::vector<mesh::SurfacePoint> sites;  // on `mesh`
  Eigen::VectorXd h;       // heights, mean zero
  Eigen::VectorXd mass;    // mu(W_i)
  Eigen::VectorXd target;  // nu, scaled to mu(M)
  Eigen::VectorXd cost;    // int_{W_i} d_i^2 dmu
  double transport_cost = 0;  // sum of cost: W2^2 between mu and the point masses (unnormalized)
  std::vector<int> face_cell;  // per face of `mesh`: the cell holding most of it
  Eigen::VectorXd face_share;  // and that cell's share of the face
  int iterations = 0;
  double max_relative_error = 0;
  bool converged = false;
  int distance_rounds = 0;  // times the distances were computed (radii grown: > 1)
  bool chordal_start = false;  // Newton started from the chordal transport's heights
  double seconds_geodesics = 0, seconds_transport = 0;
};

/// The transport from mu = density * area on `mesh` (density per input vertex, linear on
/// faces and averaged per face; empty: 1) to the point masses `masses` (any positive scale;
/// empty: equal) at `sites` (points of the input mesh). Throws Error(kInvalidArgument) for
/// counts that do not match, non-positive masses or densities, sites closer to one another
/// than the mesh resolves, and a mesh that is not connected.
GeodesicOmtResult solve_geodesic_omt(const mesh::TriMesh& mesh, const std::vector<mesh::SurfacePoint>& sites,
                                     const Eigen::VectorXd& masses, const Eigen::VectorXd& density,
                                     const GeodesicOmtOptions& options = {});

}  // namespace brenier::omt
