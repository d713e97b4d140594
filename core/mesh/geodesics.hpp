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
/// Precondition: a connected mesh whose faces have positive area (mesh::clean()).
class HeatGeodesics {
 public:
  explicit HeatGeodesics(const TriMesh& mesh, double time_factor = 1.0);
  ~HeatGeodesics();
  HeatGeodesics(const HeatGeodesics&) = delete;
  HeatGeodesics& operator=(const HeatGeodesics&) = delete;

  /// #V by sources.size(): the distance from each source point to every vertex.
  Eigen::MatrixXd distances(const std::vector<SurfacePoint>& sources) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Exact polyhedral geodesic distances from `from` to every vertex (CGAL's
/// Surface_mesh_shortest_path, Xin and Wang's window propagation): quadratic time, for
/// meshes of a few thousand vertices and for references.
Eigen::VectorXd exact_distances(const TriMesh& mesh, const SurfacePoint& from);

}  // namespace brenier::mesh
