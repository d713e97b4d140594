#include "omt/area_preserving.hpp"

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <utility>

#include "common/error.hpp"
#include "mesh/geometry.hpp"
#include "mesh/topology.hpp"
#include "omt/fold_repair.hpp"

namespace brenier::omt {

Eigen::VectorXd vertex_masses(const mesh::TriMesh& m) {
  const Eigen::VectorXd area = mesh::face_areas(m);
  Eigen::VectorXd mass = Eigen::VectorXd::Zero(m.num_vertices());
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) mass[m.F(f, k)] += area[f] / 3.0;
  return mass;
}

namespace {

// Checks the options; the vertex masses of eq. 3.30 times the region weights (sec. 6.3).
Eigen::VectorXd weighted_masses(const mesh::TriMesh& m, const AreaPreservingOptions& opt) {
  const int nv = m.num_vertices();
  if (opt.weights.size() != 0) {
    if (opt.weights.size() != nv)
      invalid("weights: " + std::to_string(opt.weights.size()) + " values for " + std::to_string(nv) + " vertices");
    for (int v = 0; v < nv; ++v)
      if (!(opt.weights[v] > 0) || !std::isfinite(opt.weights[v]))
        invalid("the weight of vertex " + std::to_string(v) + " is " + std::to_string(opt.weights[v]) +
                "; weights must be positive");
  }
  if (!(opt.t >= 0 && opt.t <= 1)) invalid("t must lie in [0, 1], got " + std::to_string(opt.t));
  Eigen::VectorXd nu = vertex_masses(m);
  if (opt.weights.size() != 0) nu = nu.cwiseProduct(opt.weights);
  return nu;
}

// A map that starts from the conformal map c, which must have converged.
AreaPreservingMap starting_from(conformal::ConformalMap c) {
  if (!c.converged)
    fail(ErrorCode::kNotConverged,
         "the conformal map did not converge: max |K - Kbar| = " + std::to_string(c.max_curvature_error));
  AreaPreservingMap out;
  out.conformal = std::move(c);
  return out;
}

}  // namespace

OmtResult transport_to_mesh_sites(const mesh::TriMesh& m, const Domain& domain, const Points& sites, const Eigen::VectorXd& nu,
                    const OmtOptions& opt) {
  OmtResult r;
  try {
    r = solve_omt(domain, sites, nu, opt);
  } catch (const Error& e) {
    if (e.code() != ErrorCode::kInvalidArgument) throw;
    fail(ErrorCode::kNotConverged, std::string("the conformal map crowds vertices below double precision: ") + e.what());
  }
  if (!r.converged) {
    // Say when the conformal map packs sites too tightly for double precision: a bisector
    // is placed to ~1e-16 / |y_i - y_j| by heights of size one, so cells much below 1e-6
    // across cannot be brought to their masses (and the damped steps hide them).
    double closest = std::numeric_limits<double>::infinity();
    for (int f = 0; f < m.num_faces(); ++f)
      for (int k = 0; k < 3; ++k)
        closest = std::min(closest, (sites.row(m.F(f, k)) - sites.row(m.F(f, (k + 1) % 3))).norm());
    char buf[300];
    std::snprintf(buf, sizeof buf,
                  "the optimal transport did not converge: max relative cell-mass error %.2e after %d Newton iterations",
                  r.max_relative_error, r.iterations);
    std::string what = buf;
    if (closest < 1e-5) {
      std::snprintf(buf, sizeof buf,
                    "; the conformal map puts neighbouring vertices as close as %.1e, below what double precision "
                    "resolves",
                    closest);
      what += buf;
    }
    fail(ErrorCode::kNotConverged, what);
  }
  return r;
}


AreaPreservingMap area_preserving_disk(const mesh::TriMesh& m, const AreaPreservingOptions& opt) {
  const int nv = m.num_vertices();
  const Eigen::VectorXd nu = weighted_masses(m, opt);
  // (1) conformal map phi: S -> D (Alg. 1).
  AreaPreservingMap out = starting_from(conformal::map_to_disk(m, opt.conformal));
  // (2) sites p_i = phi(v_i), masses nu_i scaled to the disk's area pi inside solve_omt;
  // (3) the OMT map tau from the uniform disk to (p, nu).
  Points sites = out.conformal.positions.leftCols(2);
  out.omt = transport_to_mesh_sites(m, Domain::unit_disk(), sites, nu, opt.omt);
  // (4) tau^{-1} o phi: each vertex goes to the centroid of its cell W_i = tau^{-1}(p_i).
  out.positions = mesh::Vertices::Zero(nv, 3);
  out.positions.leftCols(2) = out.omt.cells.centroid;
  if (opt.t > 0)  // phi_t = grad u_t o phi_0: (1 - t) c_i + t p_i
    out.positions.leftCols(2) = (1 - opt.t) * out.positions.leftCols(2) + opt.t * sites;
  // Centroids of neighbouring cells can come out in the wrong order where the conformal map
  // crowds the sites (a fold of the piecewise-linear map through the vertices, though tau
  // itself is a bijection); those faces are repaired locally by the mean-value Tutte
  // embedding the conformal map uses, the rest of the map kept as it is.
  // The boundary goes to the boundary: a boundary vertex's cell meets the circle, and the
  // vertex is put where the radius through its centroid meets it (this also makes the
  // fixed outline of the repair below convex, as Floater's theorem asks).
  std::vector<char> fixed(nv, 0);
  for (const auto& loop : mesh::boundary_loops(m))
    for (int v : loop) {
      fixed[v] = 1;
      const double r = out.positions.row(v).norm();
      if (r > 0) out.positions.row(v) /= r;
    }
  out.relaxed_vertices = conformal::repair_planar_folds(m, out.positions, fixed, out.folded_faces);
  return out;
}

Points stereographic_sites(const mesh::TriMesh& m, const mesh::Vertices& X, Eigen::Matrix3d& R) {
  // The north pole (infinity of the stereographic plane) goes to the centre of the face
  // with the largest image, as far from every vertex as the map allows.
  int widest = 0;
  double widest_area = -1;
  for (int f = 0; f < m.num_faces(); ++f) {
    const Eigen::Vector3d a = X.row(m.F(f, 0)), b = X.row(m.F(f, 1)), c = X.row(m.F(f, 2));
    const double area = (b - a).cross(c - a).norm();
    if (area > widest_area) widest_area = area, widest = f;
  }
  const Eigen::Vector3d pole =
      (X.row(m.F(widest, 0)) + X.row(m.F(widest, 1)) + X.row(m.F(widest, 2))).transpose().normalized();
  R = Eigen::Quaterniond::FromTwoVectors(pole, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const mesh::Vertices Y = X * R.transpose();  // rows R x
  Points sites(X.rows(), 2);
  for (Eigen::Index v = 0; v < X.rows(); ++v) sites.row(v) << Y(v, 0) / (1 - Y(v, 2)), Y(v, 1) / (1 - Y(v, 2));
  return sites;
}

AreaPreservingMap area_preserving_sphere(const mesh::TriMesh& m, const AreaPreservingOptions& opt) {
  const int nv = m.num_vertices();
  const Eigen::VectorXd nu = weighted_masses(m, opt);
  AreaPreservingMap out = starting_from(conformal::map_to_sphere(m, opt.conformal));
  const mesh::Vertices& X = out.conformal.positions;
  Eigen::Matrix3d R;
  const Points sites = stereographic_sites(m, X, R);
  out.omt = transport_to_mesh_sites(m, Domain::stereographic_sphere(), sites, nu, opt.omt);
  // Each vertex to its cell's centroid on the sphere, turned back.
  out.positions = out.omt.cells.sphere_centroid * R;  // rows R^T c
  if (opt.t > 0)
    for (int v = 0; v < nv; ++v)
      out.positions.row(v) = ((1 - opt.t) * out.positions.row(v) + opt.t * X.row(v)).normalized();
  std::vector<char> fixed(nv, 0);
  out.relaxed_vertices = conformal::untangle(m, out.positions, true, fixed, out.folded_faces);
  // Folds the local steps left: the barrier repair of fold_repair.hpp, kept only where it
  // leaves the map's area distortion no larger than it was.
  if (out.folded_faces > 0)
    out.relaxed_vertices += repair_sphere_folds_by_barrier(m, out.positions, out.folded_faces, opt.repair_progress);
  return out;
}

}  // namespace brenier::omt
