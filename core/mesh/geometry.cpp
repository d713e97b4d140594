#include "mesh/geometry.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>
#include <string>

#include "common/error.hpp"
#include "mesh/topology.hpp"

namespace brenier::mesh {

Eigen::VectorXd face_areas(const TriMesh& m) {
  Eigen::VectorXd a(m.F.rows());
  for (int f = 0; f < m.F.rows(); ++f) {
    Eigen::Vector3d p0 = m.V.row(m.F(f, 0)), p1 = m.V.row(m.F(f, 1)), p2 = m.V.row(m.F(f, 2));
    a[f] = 0.5 * (p1 - p0).cross(p2 - p0).norm();
  }
  return a;
}

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

int default_hole_vertex(const TriMesh& m) {
  Eigen::Vector3d c = area_centroid(m);
  Eigen::MatrixXd X = m.V.rowwise() - c.transpose();
  Eigen::Matrix3d cov = X.transpose() * X;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
  Eigen::Vector3d axis = es.eigenvectors().col(2);  // largest spread
  int best = 0;
  double best_d = -1;
  for (int i = 0; i < X.rows(); ++i) {
    double d = std::abs(X.row(i).dot(axis));
    if (d > best_d) {
      best_d = d;
      best = i;
    }
  }
  return best;
}

CutHole cut_hole(const TriMesh& m, std::optional<int> v) {
  Topology t = compute_topology(m);
  if (t.mesh_class != MeshClass::kSphere)
    invalid("--cut-hole needs a closed genus-0 surface; this mesh is " +
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
