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
#include "quality/quality.hpp"

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

// Folds the local untangling on the sphere left, repaired one cluster at a time: the cap of
// 60 degrees around a folded face goes onto its tangent plane by the gnomonic projection,
// under which a chord triangle is outward-facing exactly when its image turns
// counter-clockwise; there the mean-value Tutte repair of the disk map
// (repair_planar_folds, rings doubling around the folds, the cap's rim fixed) applies, and
// the moved vertices go back onto the sphere. A round is kept only if it leaves fewer folds
// and the area distortion (mean |log area ratio|) stays within 0.1 of the unrepaired map's:
// the Tutte weights pull a region toward a harmonic layout, and a repair that trades folds
// for a distorted map is no repair (the folds are then reported).
void repair_sphere_folds(const mesh::TriMesh& m, AreaPreservingMap& out) {
  const int nv = m.num_vertices(), nf = m.num_faces();
  auto folded_face = [&](const mesh::Vertices& Z, int f) { return conformal::face_folded(m, Z, f, true); };
  const double allowed =
      0.1 + quality::measure(m, out.positions, quality::Target::kSphere).area_distortion_log_abs.mean;
  std::vector<char> tried(nf, 0);
  for (int round = 0; round < 16 && out.folded_faces > 0; ++round) {
    int seed = -1;
    for (int f = 0; f < nf && seed < 0; ++f)
      if (!tried[f] && folded_face(out.positions, f)) seed = f;
    if (seed < 0) return;
    tried[seed] = 1;
    const mesh::Vertices& X = out.positions;
    const Eigen::Vector3d centre =
        (X.row(m.F(seed, 0)) + X.row(m.F(seed, 1)) + X.row(m.F(seed, 2))).transpose().normalized();
    const Eigen::Vector3d e1 = centre.unitOrthogonal(), e2 = centre.cross(e1);
    std::vector<char> inside(nv, 0), fixed(nv, 1);
    for (int v = 0; v < nv; ++v) inside[v] = X.row(v).dot(centre) > 0.5;
    std::vector<int> kept;
    for (int f = 0; f < nf; ++f)
      if (inside[m.F(f, 0)] && inside[m.F(f, 1)] && inside[m.F(f, 2)]) kept.push_back(f);
    // Free: inside vertices all of whose faces lie in the cap.
    for (int v = 0; v < nv; ++v) fixed[v] = !inside[v];
    for (int f = 0; f < nf; ++f)
      if (!(inside[m.F(f, 0)] && inside[m.F(f, 1)] && inside[m.F(f, 2)]))
        for (int k = 0; k < 3; ++k) fixed[m.F(f, k)] = 1;
    // Only the part of the cap connected to the seed face (the repair's rings must be able
    // to reach every free vertex).
    {
      std::vector<std::vector<int>> faces_of(nv);
      for (int f : kept)
        for (int k = 0; k < 3; ++k) faces_of[m.F(f, k)].push_back(f);
      std::vector<char> reached(nv, 0);
      std::vector<int> queue;
      for (int k = 0; k < 3; ++k)
        if (inside[m.F(seed, k)] && !reached[m.F(seed, k)]) reached[m.F(seed, k)] = 1, queue.push_back(m.F(seed, k));
      for (size_t q = 0; q < queue.size(); ++q)
        for (int f : faces_of[queue[q]])
          for (int k = 0; k < 3; ++k)
            if (!reached[m.F(f, k)]) reached[m.F(f, k)] = 1, queue.push_back(m.F(f, k));
      for (int v = 0; v < nv; ++v)
        if (!reached[v]) fixed[v] = 1;
    }
    mesh::TriMesh cap{m.V, mesh::Faces(static_cast<int>(kept.size()), 3)};
    for (size_t k = 0; k < kept.size(); ++k) cap.F.row(static_cast<int>(k)) = m.F.row(kept[k]);
    mesh::Vertices P = mesh::Vertices::Zero(nv, 3);
    for (int v = 0; v < nv; ++v)
      if (inside[v]) {
        const Eigen::Vector3d x = X.row(v);
        P.row(v) << x.dot(e1) / x.dot(centre), x.dot(e2) / x.dot(centre), 0;
      }
    int planar_left = 0;
    const int moved = conformal::repair_planar_folds(cap, P, fixed, planar_left);
    if (moved == 0) continue;
    mesh::Vertices back = X;
    for (int v = 0; v < nv; ++v)
      if (!fixed[v]) back.row(v) = (centre + P(v, 0) * e1 + P(v, 1) * e2).normalized().transpose();
    int left = 0;
    for (int f = 0; f < nf; ++f) left += folded_face(back, f);
    const double after = quality::measure(m, back, quality::Target::kSphere).area_distortion_log_abs.mean;
    if (left < out.folded_faces && after <= allowed) {
      out.positions = std::move(back);
      out.folded_faces = left;
      out.relaxed_vertices += moved;
    }
  }
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
  if (out.folded_faces > 0) repair_sphere_folds(m, out);
  return out;
}

}  // namespace brenier::omt
