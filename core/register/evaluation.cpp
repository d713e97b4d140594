// Ground truth for registration (evaluation.hpp): deformations, CGAL's isotropic remeshing and
// exact geodesics.
#include "register/evaluation.hpp"

#include <CGAL/Polygon_mesh_processing/remesh.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "common/error.hpp"
#include "mesh/cgal_surface.hpp"
#include "mesh/geometry.hpp"

namespace brenier::registration {

namespace {

using mesh::cgal::Paths;
using SM = mesh::cgal::Surface;
using mesh::cgal::to_surface_mesh;

// Principal axes of the vertices (columns, by decreasing spread) and their centroid.
void principal_axes(const mesh::Vertices& V, Eigen::Vector3d& c, Eigen::Matrix3d& axes) {
  c = V.colwise().mean().transpose();
  const Eigen::MatrixXd X = V.rowwise() - c.transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(X.transpose() * X);
  axes = es.eigenvectors().rowwise().reverse();
}

}  // namespace

const char* deformation_name(Deformation d) {
  switch (d) {
    case Deformation::kNone: return "none";
    case Deformation::kBend: return "bend";
    case Deformation::kTwist: return "twist";
    case Deformation::kStretch: return "stretch";
  }
  return "?";
}

mesh::Vertices deform(const mesh::Vertices& V, Deformation d, double amount) {
  Eigen::Vector3d c;
  Eigen::Matrix3d E;
  principal_axes(V, c, E);
  const Eigen::MatrixXd local = (V.rowwise() - c.transpose()) * E;  // coordinates along the axes
  const double half = std::max(local.col(0).cwiseAbs().maxCoeff(), 1e-300);
  Eigen::MatrixXd out = local;
  for (Eigen::Index i = 0; i < local.rows(); ++i) {
    const double s = local(i, 0), t = local(i, 1), u = local(i, 2);
    if (d == Deformation::kBend && amount != 0) {
      // The axis onto an arc of angle amount * pi / 2 over its length 2 * half: radius rho.
      const double rho = 2 * half / (amount * M_PI / 2), a = s / rho;
      out(i, 0) = (rho - t) * std::sin(a);
      out(i, 1) = rho - (rho - t) * std::cos(a);
    } else if (d == Deformation::kTwist) {
      const double a = amount * M_PI / 2 * s / half;
      out(i, 1) = std::cos(a) * t - std::sin(a) * u;
      out(i, 2) = std::sin(a) * t + std::cos(a) * u;
    } else if (d == Deformation::kStretch) {
      out(i, 0) = s * (1 + amount);
      out(i, 1) = t / (1 + amount);
    }
  }
  mesh::Vertices W = (out * E.transpose()).rowwise() + c.transpose();
  return W;
}

mesh::TriMesh remesh(const mesh::TriMesh& m, double edge_scale, int iterations) {
  SM sm = to_surface_mesh(m);
  double total = 0;
  long n = 0;
  for (auto e : sm.edges()) {
    total += std::sqrt(CGAL::squared_distance(sm.point(sm.vertex(e, 0)), sm.point(sm.vertex(e, 1))));
    ++n;
  }
  const double target = edge_scale * total / std::max(1L, n);
  namespace PMP = CGAL::Polygon_mesh_processing;
  PMP::isotropic_remeshing(faces(sm), target, sm, CGAL::parameters::number_of_iterations(iterations));
  sm.collect_garbage();
  mesh::TriMesh out;
  out.V.resize(static_cast<Eigen::Index>(sm.number_of_vertices()), 3);
  for (auto v : sm.vertices()) {
    const auto& p = sm.point(v);
    out.V.row(static_cast<Eigen::Index>(v.idx())) << p.x(), p.y(), p.z();
  }
  out.F.resize(static_cast<Eigen::Index>(sm.number_of_faces()), 3);
  for (auto f : sm.faces()) {
    int k = 0;
    for (auto v : vertices_around_face(sm.halfedge(f), sm)) out.F(static_cast<Eigen::Index>(f.idx()), k++) = static_cast<int>(v.idx());
  }
  return out;
}

std::vector<SurfacePoint> nearest_points(const mesh::TriMesh& on, const mesh::Vertices& points) {
  // locate() on the plane falls back to the nearest point of the mesh: the same query.
  return locate(on.F, on.V, points, false);
}

std::vector<double> geodesic_distances(const mesh::TriMesh& m, const std::vector<SurfacePoint>& from,
                                       const std::vector<SurfacePoint>& to) {
  const SM sm = to_surface_mesh(m);
  auto cgal_bary = [&](const SurfacePoint& p) { return mesh::cgal::location(sm, m, p); };
  std::vector<double> d(from.size(), 0);
  for (long i = 0; i < static_cast<long>(from.size()); ++i) {
    // Both ways, the shorter kept: CGAL 5.5 returns a too long path one way on some flat
    // configurations (a regular grid, from (0.1, 0.1) to (0.9, 0.8): 1.169 for 1.063, the
    // other way exact); each way's answer is the length of a path on the surface, so the
    // shorter is the nearer bound.
    const auto a = cgal_bary(from[static_cast<size_t>(i)]), b = cgal_bary(to[static_cast<size_t>(i)]);
    Paths ab(sm), ba(sm);
    ab.add_source_point(a.first, a.second);
    ba.add_source_point(b.first, b.second);
    d[static_cast<size_t>(i)] = std::min(ab.shortest_distance_to_source_points(b.first, b.second).first,
                                         ba.shortest_distance_to_source_points(a.first, a.second).first);
  }
  return d;
}

std::vector<int> spread_vertices(const mesh::Vertices& V, int k) {
  std::vector<int> out;
  if (V.rows() == 0 || k <= 0) return out;
  const Eigen::RowVector3d c = V.colwise().mean();
  Eigen::Index first = 0;
  (V.rowwise() - c).rowwise().squaredNorm().maxCoeff(&first);
  Eigen::VectorXd dist = Eigen::VectorXd::Constant(V.rows(), 1e300);
  int next = static_cast<int>(first);
  for (int n = 0; n < k && n < V.rows(); ++n) {
    out.push_back(next);
    dist = dist.cwiseMin((V.rowwise() - V.row(next)).rowwise().squaredNorm());
    Eigen::Index far = 0;
    dist.maxCoeff(&far);
    next = static_cast<int>(far);
  }
  return out;
}

std::vector<double> cumulative_curve(const std::vector<double>& errors, const std::vector<double>& thresholds) {
  std::vector<double> sorted = errors;
  std::sort(sorted.begin(), sorted.end());
  std::vector<double> out;
  for (double t : thresholds) {
    const auto n = std::upper_bound(sorted.begin(), sorted.end(), t) - sorted.begin();
    out.push_back(sorted.empty() ? 0.0 : static_cast<double>(n) / static_cast<double>(sorted.size()));
  }
  return out;
}

TruthPair make_truth_pair(const mesh::TriMesh& m, Deformation d, double amount, double edge_scale, int landmarks) {
  TruthPair p;
  p.source = m;
  const mesh::TriMesh r = remesh(m, edge_scale);
  p.truth = nearest_points(r, m.V);  // the remeshed surface lies on the input's
  p.target = r;
  p.target.V = deform(r.V, d, amount);
  for (int v : spread_vertices(m.V, landmarks)) {
    p.source_landmarks.push_back(v);
    Eigen::Index j = 0;
    (r.V.rowwise() - m.V.row(v)).rowwise().squaredNorm().minCoeff(&j);
    p.target_landmarks.push_back(static_cast<int>(j));
  }
  return p;
}

std::vector<double> registration_errors(const TruthPair& pair, const std::vector<SurfacePoint>& found, int samples) {
  const int n = pair.source.num_vertices();
  const int k = std::max(1, std::min(samples, n));
  std::vector<SurfacePoint> from, to;
  for (int i = 0; i < k; ++i) {
    const auto v = static_cast<size_t>(static_cast<int64_t>(i) * n / k);
    from.push_back(pair.truth[v]);
    to.push_back(found[v]);
  }
  std::vector<double> d = geodesic_distances(pair.target, from, to);
  const double scale = std::sqrt(mesh::total_area(pair.target));
  for (double& x : d) x /= scale;
  return d;
}

}  // namespace brenier::registration
