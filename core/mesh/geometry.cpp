#include "mesh/geometry.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>
#include <limits>
#include <queue>
#include <string>
#include <utility>
#include <vector>

#include "common/error.hpp"
#include "mesh/topology.hpp"

namespace brenier::mesh {

Eigen::VectorXd face_areas(const Faces& F, const Vertices& X) {
  Eigen::VectorXd a(F.rows());
  for (int f = 0; f < F.rows(); ++f) {
    Eigen::Vector3d p0 = X.row(F(f, 0)), p1 = X.row(F(f, 1)), p2 = X.row(F(f, 2));
    a[f] = 0.5 * (p1 - p0).cross(p2 - p0).norm();
  }
  return a;
}

Eigen::VectorXd face_areas(const TriMesh& m) { return face_areas(m.F, m.V); }

double total_area(const TriMesh& m) { return face_areas(m).sum(); }

Eigen::Vector3d area_centroid(const TriMesh& m) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double total = 0;
  for (int f = 0; f < m.F.rows(); ++f) {
    Eigen::Vector3d p0 = m.V.row(m.F(f, 0)), p1 = m.V.row(m.F(f, 1)), p2 = m.V.row(m.F(f, 2));
    double a = 0.5 * (p1 - p0).cross(p2 - p0).norm();
    c += a * (p0 + p1 + p2) / 3.0;
    total += a;
  }
  return total > 0 ? Eigen::Vector3d(c / total) : Eigen::Vector3d(m.V.colwise().mean().transpose());
}

Eigen::VectorXd vertex_areas(const TriMesh& m) {
  Eigen::VectorXd fa = face_areas(m);
  Eigen::VectorXd va = Eigen::VectorXd::Zero(m.V.rows());
  for (int f = 0; f < m.F.rows(); ++f)
    for (int k = 0; k < 3; ++k) va[m.F(f, k)] += fa[f] / 3.0;
  return va;
}

Normalization normalize(TriMesh& m, double target_area) {
  if (!(target_area > 0)) invalid("normalization target area must be positive");
  double a = total_area(m);
  if (!(a > 0) || !std::isfinite(a)) invalid("cannot normalize a mesh of zero or undefined area");
  Normalization n;
  n.centre = area_centroid(m);
  n.scale = std::sqrt(target_area / a);
  m.V = (n.scale * (m.V.rowwise() - n.centre.transpose())).eval();
  return n;
}

namespace {
// Dijkstra over mesh edges (Euclidean lengths) from `src`; returns distances and parents.
std::pair<std::vector<double>, std::vector<int>> dijkstra(const TriMesh& m, int src) {
  const int nv = m.num_vertices();
  std::vector<std::vector<std::pair<int, double>>> adj(nv);
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) {
      int a = m.F(f, k), b = m.F(f, (k + 1) % 3);
      double l = (m.V.row(a) - m.V.row(b)).norm();
      adj[a].push_back({b, l});
      adj[b].push_back({a, l});
    }
  std::vector<double> d(nv, std::numeric_limits<double>::infinity());
  std::vector<int> parent(nv, -1);
  std::priority_queue<std::pair<double, int>, std::vector<std::pair<double, int>>, std::greater<>> q;
  d[src] = 0;
  q.push({0, src});
  while (!q.empty()) {
    auto [dv, v] = q.top();
    q.pop();
    if (dv > d[v]) continue;
    for (auto [w, l] : adj[v])
      if (dv + l < d[w]) {
        d[w] = dv + l;
        parent[w] = v;
        q.push({d[w], w});
      }
  }
  return {std::move(d), std::move(parent)};
}
}  // namespace

int default_hole_vertex(const TriMesh& m) {
  // Double sweep: a = farthest from vertex 0, b = farthest from a (a near-diameter pair);
  // the vertex minimizing max(d(a, v), d(b, v)) is close to the surface's centre, so
  // every protrusion is as near to the hole as it can be. A conformal map squeezes a
  // protrusion exponentially in its distance from the hole (e^{-2 pi length / girth}), so
  // this keeps long limbs representable in double precision.
  auto far = [](const std::vector<double>& d) {
    int best = 0;
    for (int i = 1; i < static_cast<int>(d.size()); ++i)
      if (std::isfinite(d[i]) && d[i] > d[best]) best = i;
    return best;
  };
  int a = far(dijkstra(m, 0).first);
  auto da = dijkstra(m, a).first;
  int b = far(da);
  auto db = dijkstra(m, b).first;
  int v = 0;
  double best = std::numeric_limits<double>::infinity();
  for (int i = 0; i < m.num_vertices(); ++i) {
    double e = std::max(da[i], db[i]);  // the vertex the two ends of the diameter share best
    if (e < best) {
      best = e;
      v = i;
    }
  }
  return v;
}

CutHole cut_hole(const TriMesh& m, std::optional<int> v) {
  Topology t = compute_topology(m);
  if (t.mesh_class != MeshClass::kSphere)
    invalid("cutting a hole ({cut_hole}) needs a closed genus-0 surface; this mesh is " +
            std::string(class_name(t.mesh_class)) + " (genus " + std::to_string(t.genus) + ", " +
            std::to_string(t.boundary_loops) + " boundary loops)");
  int hole = v ? *v : default_hole_vertex(m);
  if (hole < 0 || hole >= m.V.rows())
    invalid("hole vertex " + std::to_string(hole) + " is out of range (the mesh has " +
            std::to_string(m.V.rows()) + " vertices)");
  CutHole out;
  out.vertex = hole;
  std::vector<int> remap(m.V.rows());
  int n = 0;
  for (int i = 0; i < m.V.rows(); ++i) {
    remap[i] = i == hole ? -1 : n++;
    if (i != hole) out.vertex_origin.push_back(i);
  }
  out.mesh.V.resize(n, 3);
  for (int i = 0; i < m.V.rows(); ++i)
    if (remap[i] >= 0) out.mesh.V.row(remap[i]) = m.V.row(i);
  std::vector<int> kept;
  for (int f = 0; f < m.F.rows(); ++f)
    if (m.F(f, 0) != hole && m.F(f, 1) != hole && m.F(f, 2) != hole) kept.push_back(f);
  out.mesh.F.resize(static_cast<Eigen::Index>(kept.size()), 3);
  for (size_t j = 0; j < kept.size(); ++j)
    for (int k = 0; k < 3; ++k) out.mesh.F(j, k) = remap[m.F(kept[j], k)];
  out.face_origin = std::move(kept);
  // A manifold sphere minus an open vertex star is a disk; check it rather than trust it
  // (e.g. a vertex whose star is the whole mesh, as on a tetrahedron's apex, leaves a disk
  // too, but a 2-face pillow leaves nothing).
  if (out.mesh.F.rows() == 0 || compute_topology(out.mesh).mesh_class != MeshClass::kDisk)
    invalid("removing the star of vertex " + std::to_string(hole) + " does not leave a disk");
  return out;
}

}  // namespace brenier::mesh
