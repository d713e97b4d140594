// Geodesic distance fields on a triangle mesh: the cost of Riemannian optimal transport
// (dissertation sec. 3.2.6, Alg. 4: "compute the geodesic from p_i to every other vertex").
// Two ways, as the issue allows: the heat method, whose two sparse systems are factored
// once and then serve every source, and CGAL's exact polyhedral geodesics for small meshes
// and references.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::mesh {

/// The heat method of Crane, Weischedel and Wardetzky ("Geodesics in heat", 2013) with the
/// cotangent Laplacian L (the P1 stiffness matrix: positive semidefinite on any mesh) and
/// the lumped mass matrix M:
///   1. heat flow for time t = time_factor * (mean edge length)^2: (M + t L) u = delta_source;
///   2. the unit field X = -grad u / |grad u| on every face;
///   3. the potential whose gradient best fits X: L phi = -div X (integrated divergence;
///      one vertex held, the system being consistent: a constant field per face has zero
///      divergence, so div X sums to zero);
///   4. distance = phi - min phi (the least value: on stars with obtuse corners phi may
///      peak at the source itself).
/// Both systems are factored by CHOLMOD in the constructor; distances() solves sources in
/// blocks (a multi-column solve), the face and vertex loops in parallel.
/// Accuracy against CGAL's exact geodesics, six sources each, error over the largest distance:
/// mean 0.4 % on an icosphere (2,562 vertices), 0.9-1.2 % on lion-head and mannequin-devil,
/// worst 7-10 % (far from the source, where the heat flow is under-resolved). Larger times
/// (2-16 h^2) lowered the worst error but raised the mean; averaging with a Dirichlet heat
/// flow (the paper's advice at boundaries) gained 0.1 % on lion-head for a third solve, and
/// was left out.
/// Precondition: a connected mesh whose faces have positive area (mesh::clean()).
class HeatGeodesics {
 public:
  explicit HeatGeodesics(const TriMesh& mesh, double time_factor = 1.0);
  ~HeatGeodesics();
  HeatGeodesics(const HeatGeodesics&) = delete;
  HeatGeodesics& operator=(const HeatGeodesics&) = delete;

  /// #V by sources.size(): the distance from each source point to every vertex. Not
  /// reentrant: the solves reuse the object's buffers.
  Eigen::MatrixXd distances(const std::vector<SurfacePoint>& sources);
  /// The same into `out` (resized; a buffer of the same size is reused, not reallocated).
  void distances(const std::vector<SurfacePoint>& sources, Eigen::MatrixXd& out);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Exact polyhedral geodesic distances from `from` to every vertex (CGAL's
/// Surface_mesh_shortest_path, Xin and Wang's window propagation): quadratic time, for
/// meshes of a few thousand vertices and for references.
Eigen::VectorXd exact_distances(const TriMesh& mesh, const SurfacePoint& from);

}  // namespace brenier::mesh
