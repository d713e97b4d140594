// Ground truth for registration (evaluation.hpp): deformations, CGAL's isotropic remeshing and
// exact geodesics.
#include "register/evaluation.hpp"

#include <CGAL/Polygon_mesh_processing/remesh.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <complex>
#include <Eigen/Geometry>
#include <cstdio>
#include <cstdlib>

#include "common/error.hpp"
#include "register/domain_match.hpp"
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

namespace {

// The faces of m that may meet the ball of radius r around x (a vertex within r plus the
// face's longest edge), as a mesh of their own; `face_of[f]` is the patch's face f in m.
mesh::TriMesh ball_patch(const mesh::TriMesh& m, const Eigen::Vector3d& x, double r, std::vector<int>& face_of) {
  std::vector<int> vertex_of(static_cast<size_t>(m.num_vertices()), -1);
  std::vector<int> kept_vertices;
  face_of.clear();
  for (int f = 0; f < m.num_faces(); ++f) {
    double near = 1e300, edge = 0;
    for (int k = 0; k < 3; ++k) {
      near = std::min(near, (m.V.row(m.F(f, k)).transpose() - x).norm());
      edge = std::max(edge, (m.V.row(m.F(f, k)) - m.V.row(m.F(f, (k + 1) % 3))).norm());
    }
    if (near > r + edge) continue;
    face_of.push_back(f);
    for (int k = 0; k < 3; ++k)
      if (vertex_of[static_cast<size_t>(m.F(f, k))] < 0) {
        vertex_of[static_cast<size_t>(m.F(f, k))] = static_cast<int>(kept_vertices.size());
        kept_vertices.push_back(m.F(f, k));
      }
  }
  mesh::TriMesh p;
  p.V.resize(static_cast<Eigen::Index>(kept_vertices.size()), 3);
  for (size_t i = 0; i < kept_vertices.size(); ++i) p.V.row(static_cast<Eigen::Index>(i)) = m.V.row(kept_vertices[i]);
  p.F.resize(static_cast<Eigen::Index>(face_of.size()), 3);
  for (size_t f = 0; f < face_of.size(); ++f)
    for (int k = 0; k < 3; ++k) p.F(static_cast<Eigen::Index>(f), k) = vertex_of[static_cast<size_t>(m.F(face_of[f], k))];
  return p;
}

// The exact geodesic distance between a and b on m, both ways, the shorter kept: CGAL 5.5
// returns a too long path one way on some flat configurations (a regular grid, from (0.1,
// 0.1) to (0.9, 0.8): 1.169 for 1.063, the other way exact); each way's answer is the
// length of a path on the surface, so the shorter is the nearer bound.
double exact_between(const mesh::TriMesh& m, const SurfacePoint& a, const SurfacePoint& b) {
  const SM sm = to_surface_mesh(m);
  const auto la = mesh::cgal::location(sm, m, a), lb = mesh::cgal::location(sm, m, b);
  Paths ab(sm), ba(sm);
  ab.add_source_point(la.first, la.second);
  ba.add_source_point(lb.first, lb.second);
  return std::min(ab.shortest_distance_to_source_points(lb.first, lb.second).first,
                  ba.shortest_distance_to_source_points(la.first, la.second).first);
}

}  // namespace

std::vector<double> geodesic_distances(const mesh::TriMesh& m, const std::vector<SurfacePoint>& from,
                                       const std::vector<SurfacePoint>& to) {
  // On a patch: the faces that may meet the ball of radius r around the first point, r
  // starting at twice the straight distance. A path of length L <= r from there stays in
  // the ball, so when the patch's distance L is at most r it is the whole mesh's (the mesh's
  // shortest path is no longer than L, so it lies in the ball too); otherwise r doubles. The
  // whole mesh is the fallback (a patch that is not a manifold, or r past the mesh's size).
  // Pairs run in parallel, each with its own CGAL objects.
  std::vector<double> d(from.size(), 0);
  const double diagonal = (m.V.colwise().maxCoeff() - m.V.colwise().minCoeff()).norm();
#pragma omp parallel for schedule(dynamic, 4)
  for (long i = 0; i < static_cast<long>(from.size()); ++i) {
    const SurfacePoint& a = from[static_cast<size_t>(i)];
    const SurfacePoint& b = to[static_cast<size_t>(i)];
    const Eigen::Vector3d pa = positions(m, {a}).row(0).transpose(), pb = positions(m, {b}).row(0).transpose();
    double r = std::max(2 * (pa - pb).norm(), 1e-9 * diagonal), found = -1;
    std::vector<int> face_of;
    for (; r < diagonal && found < 0; r *= 2) {
      const mesh::TriMesh patch = ball_patch(m, pa, r, face_of);
      auto in_patch = [&](const SurfacePoint& p) -> SurfacePoint {
        const auto it = std::lower_bound(face_of.begin(), face_of.end(), p.face);
        return {it != face_of.end() && *it == p.face ? static_cast<int>(it - face_of.begin()) : -1, p.bary};
      };
      const SurfacePoint qa = in_patch(a), qb = in_patch(b);
      if (qa.face < 0 || qb.face < 0) continue;
      try {
        const double L = exact_between(patch, qa, qb);
        if (L <= r) found = L;
      } catch (const Error&) {
        break;  // not a manifold patch: the whole mesh
      }
    }
    try {
      d[static_cast<size_t>(i)] = found >= 0 ? found : exact_between(m, a, b);
    } catch (const Error&) {
      d[static_cast<size_t>(i)] = std::nan("");  // an exception may not leave the parallel loop
    }
  }
  for (size_t i = 0; i < d.size(); ++i)
    if (std::isnan(d[i])) fail(ErrorCode::kInternal, "geodesic_distances: pair " + std::to_string(i) + " has no CGAL location");
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

std::vector<double> domain_disagreement(const TruthPair& pair, const mesh::Vertices& source_domain,
                                        const mesh::Vertices& target_domain, bool sphere) {
  std::vector<Eigen::Vector3d> x, y;
  for (Eigen::Index v = 0; v < source_domain.rows(); ++v) {
    const SurfacePoint& t = pair.truth[static_cast<size_t>(v)];
    Eigen::Vector3d q = Eigen::Vector3d::Zero();
    for (int k = 0; k < 3; ++k) q += t.bary[k] * target_domain.row(pair.target.F(t.face, k)).transpose();
    x.push_back(source_domain.row(v).transpose());
    y.push_back(q);
  }
  Eigen::Matrix3d R = best_rotation(x, y);
  if (!sphere) {  // the turn about the disk's centre
    std::complex<double> sum = 0;
    for (size_t i = 0; i < x.size(); ++i) sum += std::conj(std::complex<double>(x[i].x(), x[i].y())) * std::complex<double>(y[i].x(), y[i].y());
    R = Eigen::AngleAxisd(std::arg(sum), Eigen::Vector3d::UnitZ()).toRotationMatrix();
  }
  std::vector<double> e;
  for (size_t i = 0; i < x.size(); ++i) e.push_back((R * x[i] - y[i]).norm());
  return e;
}

}  // namespace brenier::registration
