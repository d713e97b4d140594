// Locating domain points in the target's domain mesh (Alg. 7 step 3) with CGAL's AABB tree.
#include "register/correspondence.hpp"

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Simple_cartesian.h>

#include <Eigen/Geometry>
#include <algorithm>

#include "common/error.hpp"
#include "mesh/topology.hpp"

namespace brenier::registration {

namespace {

using K = CGAL::Simple_cartesian<double>;
using Triangle = K::Triangle_3;
using Iterator = std::vector<Triangle>::const_iterator;
using Primitive = CGAL::AABB_triangle_primitive<K, Iterator>;
using Tree = CGAL::AABB_tree<CGAL::AABB_traits<K, Primitive>>;

K::Point_3 point(const Eigen::Vector3d& x) { return {x.x(), x.y(), x.z()}; }
Eigen::Vector3d vec(const K::Point_3& p) { return {p.x(), p.y(), p.z()}; }

// Barycentric coordinates of x (in or near the plane of a, b, c), clamped into the triangle.
Eigen::Vector3d barycentric(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                            const Eigen::Vector3d& x) {
  const Eigen::Vector3d n = (b - a).cross(c - a);
  const double nn = n.squaredNorm();
  if (!(nn > 0)) return {1, 0, 0};
  Eigen::Vector3d w((c - b).cross(x - b).dot(n) / nn, (a - c).cross(x - c).dot(n) / nn, 0);
  w.z() = 1 - w.x() - w.y();
  w = w.cwiseMax(0.0);
  const double s = w.sum();
  return s > 0 ? Eigen::Vector3d(w / s) : Eigen::Vector3d(1, 0, 0);
}

}  // namespace

struct DomainLocator::Tree {
  std::vector<Triangle> tris;
  brenier::registration::Tree tree;
};

DomainLocator::DomainLocator(const mesh::Faces& F, const mesh::Vertices& domain, bool sphere)
    : F_(F), domain_(domain), sphere_(sphere), tree_(std::make_unique<Tree>()) {
  tree_->tris.reserve(static_cast<size_t>(F.rows()));
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    tree_->tris.emplace_back(point(domain.row(F(f, 0)).transpose()), point(domain.row(F(f, 1)).transpose()),
                             point(domain.row(F(f, 2)).transpose()));
  tree_->tree.insert(tree_->tris.cbegin(), tree_->tris.cend());
  tree_->tree.build();
  tree_->tree.accelerate_distance_queries();
  neighbors_ = mesh::face_neighbors(F);
}

bool DomainLocator::walk(int from, const Eigen::Vector3d& x, SurfacePoint& out) const {
  constexpr int kLongest = 64;
  int f = from;
  for (int step = 0; step < kLongest && f >= 0; ++step) {
    const Eigen::Vector3d a = domain_.row(F_(f, 0)).transpose();
    const Eigen::Vector3d e1 = domain_.row(F_(f, 1)).transpose() - a, e2 = domain_.row(F_(f, 2)).transpose() - a;
    const Eigen::Vector3d d = x - a;
    double w1, w2;
    if (sphere_) {
      // The ray's coordinates: lambda_k proportional to x . (the cross product of the other two
      // corners), which for the corners b = a + e1, c = a + e2 read d . (e2 x a) and
      // d . (a x e1) over x . (e1 x e2), from differences so that tiny triangles keep their digits.
      const double xn = x.dot(e1.cross(e2));
      if (!(xn > 0)) return false;  // the ray misses the triangle's front
      w1 = d.dot(e2.cross(a)) / xn;
      w2 = d.dot(a.cross(e1)) / xn;
    } else {
      const double det = e1.x() * e2.y() - e1.y() * e2.x();
      if (det == 0) return false;
      // (w1, w2) = D^-1 (x - a), D = [b - a, c - a]
      w1 = (e2.y() * d.x() - e2.x() * d.y()) / det;
      w2 = (e1.x() * d.y() - e1.y() * d.x()) / det;
    }
    const Eigen::Vector3d bary(1 - (w1 + w2), w1, w2);
    Eigen::Index k;
    if (bary.minCoeff(&k) >= 0) {
      out = {f, bary};
      return true;
    }
    f = neighbors_[static_cast<size_t>(f)][static_cast<size_t>((k + 1) % 3)];  // across the edge opposite corner k
  }
  return false;
}

DomainLocator::~DomainLocator() = default;

std::vector<SurfacePoint> DomainLocator::operator()(const mesh::Vertices& points) const {
  const Tree& t = *tree_;
  std::vector<SurfacePoint> out(static_cast<size_t>(points.rows()));
  // The tree's queries are const; each thread asks its own.
#pragma omp parallel for schedule(dynamic, 256)
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    const Eigen::Vector3d x = points.row(i).transpose();
    int face = -1;
    Eigen::Vector3d at = x;
    if (sphere_) {
      const K::Ray_3 ray(K::Point_3(0, 0, 0), point(x));
      if (auto hit = t.tree.first_intersection(ray)) {
        if (const K::Point_3* p = boost::get<K::Point_3>(&hit->first)) {
          face = static_cast<int>(hit->second - t.tris.cbegin());
          at = vec(*p);
        }
      }
    }
    if (face < 0) {
      const auto hit = t.tree.closest_point_and_primitive(point(x));
      face = static_cast<int>(hit.second - t.tris.cbegin());
      at = vec(hit.first);
    }
    SurfacePoint& sp = out[static_cast<size_t>(i)];
    sp.face = face;
    sp.bary = barycentric(domain_.row(F_(face, 0)).transpose(), domain_.row(F_(face, 1)).transpose(),
                          domain_.row(F_(face, 2)).transpose(), at);
  }
  return out;
}

std::vector<SurfacePoint> locate(const mesh::Faces& F, const mesh::Vertices& domain, const mesh::Vertices& points,
                                 bool sphere) {
  return DomainLocator(F, domain, sphere)(points);
}

mesh::Vertices positions(const mesh::TriMesh& mesh, const std::vector<SurfacePoint>& points) {
  mesh::Vertices X(static_cast<Eigen::Index>(points.size()), 3);
  for (size_t i = 0; i < points.size(); ++i) {
    const auto& p = points[i];
    X.row(static_cast<Eigen::Index>(i)) = p.bary[0] * mesh.V.row(mesh.F(p.face, 0)) + p.bary[1] * mesh.V.row(mesh.F(p.face, 1)) +
                                          p.bary[2] * mesh.V.row(mesh.F(p.face, 2));
  }
  return X;
}

int flipped_morph_faces(const mesh::Faces& F, const mesh::Vertices& morph, const mesh::TriMesh& target,
                        const std::vector<int>& corner_face) {
  auto unit_normal = [&](int t) -> Eigen::Vector3d {
    const Eigen::Vector3d ta = target.V.row(target.F(t, 0)), tb = target.V.row(target.F(t, 1)), tc = target.V.row(target.F(t, 2));
    return (tb - ta).cross(tc - ta).normalized();
  };
  mesh::Vertices centroids(F.rows(), 3);
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    centroids.row(f) = (morph.row(F(f, 0)) + morph.row(F(f, 1)) + morph.row(F(f, 2))) / 3;
  const std::vector<SurfacePoint> near = locate(target.F, target.V, centroids, false);
  int flipped = 0;
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const Eigen::Vector3d a = morph.row(F(f, 0)), b = morph.row(F(f, 1)), c = morph.row(F(f, 2));
    const Eigen::Vector3d n = (b - a).cross(c - a);
    // Faces collapsed onto a point or a line (zero normal) are not counted.
    bool against = n.dot(unit_normal(near[static_cast<size_t>(f)].face)) < 0;
    if (against && !corner_face.empty()) {
      Eigen::Vector3d corners = Eigen::Vector3d::Zero();
      for (int k = 0; k < 3; ++k) corners += unit_normal(corner_face[static_cast<size_t>(F(f, k))]);
      against = n.dot(corners) < 0;
    }
    flipped += against;
  }
  return flipped;
}

int chart_flipped_faces(const mesh::Faces& F, const std::vector<SurfacePoint>& points, const mesh::Faces& target_F,
                        const mesh::Vertices& chart, bool sphere) {
  if (chart.rows() == 0 || target_F.rows() == 0) invalid("the chart has no vertices or no faces");
  if (target_F.minCoeff() < 0 || target_F.maxCoeff() >= chart.rows()) invalid("a target face has a corner the chart does not have");
  for (const SurfacePoint& p : points)
    if (p.face < 0 || p.face >= target_F.rows()) invalid("a point lies on a face the chart does not have");
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      if (F(f, k) < 0 || static_cast<size_t>(F(f, k)) >= points.size()) invalid("a face has a corner without a point");
  // Signed area in the chart: on the plane the z of the edges' cross product; on the sphere
  // det(a, b, c), the orientation seen from outside (the triangles are far below a hemisphere).
  auto orientation = [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
    return sphere ? a.dot(b.cross(c)) : (b - a).cross(c - a).z();
  };
  auto signed_area = [&](const mesh::Vertices& X, const mesh::Faces& G, Eigen::Index f) {
    return orientation(X.row(G(f, 0)).transpose(), X.row(G(f, 1)).transpose(), X.row(G(f, 2)).transpose());
  };
  double reference = 0;
  for (Eigen::Index t = 0; t < target_F.rows(); ++t) reference += signed_area(chart, target_F, t);
  if (!(reference != 0)) invalid("the chart gives the target's faces no orientation");
  mesh::TriMesh charted;
  charted.V = chart;
  charted.F = target_F;
  const mesh::Vertices placed = positions(charted, points);  // each point once, by its barycentric coordinates
  int flipped = 0;
  for (Eigen::Index f = 0; f < F.rows(); ++f) flipped += signed_area(placed, F, f) * reference < 0;
  return flipped;
}

}  // namespace brenier::registration
