#include "quality/quality.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>

#include "mesh/geometry.hpp"

namespace brenier::quality {
namespace {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;

// The triangle in an orthonormal frame of its own plane: p0 at 0, p1 on the x axis.
// `normal` chooses which side is "up" (for planar images, +z).
std::array<Vec2, 3> flatten(const Vec3& p0, const Vec3& p1, const Vec3& p2) {
  Vec3 e1 = p1 - p0;
  double l = e1.norm();
  e1 /= l;
  Vec3 n = (p1 - p0).cross(p2 - p0);
  Vec3 e2 = n.cross(e1).normalized();
  return {Vec2(0, 0), Vec2(l, 0), Vec2((p2 - p0).dot(e1), (p2 - p0).dot(e2))};
}

// The 2x2 linear part of the affine map taking triangle s onto triangle t.
Eigen::Matrix2d affine(const std::array<Vec2, 3>& s, const std::array<Vec2, 3>& t) {
  Eigen::Matrix2d S, D;
  S << s[1] - s[0], s[2] - s[0];
  D << t[1] - t[0], t[2] - t[0];
  return D * S.inverse();
}

double angle(const Vec3& a, const Vec3& b, const Vec3& c) {  // at a
  return std::atan2((b - a).cross(c - a).norm(), (b - a).dot(c - a));
}

}  // namespace

Eigen::VectorXd area_log_ratios(const mesh::TriMesh& surface, const mesh::Vertices& image) {
  const int nf = surface.num_faces();
  const Eigen::VectorXd a_src = mesh::face_areas(surface), a_img = mesh::face_areas(surface.F, image);
  const double ts = a_src.sum(), ti = a_img.sum();
  Eigen::VectorXd out(nf);
  for (int f = 0; f < nf; ++f) out[f] = std::log((a_img[f] / ti) / (a_src[f] / ts));
  return out;
}

Stats stats(std::vector<double> v) {
  Stats s;
  if (v.empty()) return s;
  double sum = 0;
  for (double x : v) sum += x;
  s.mean = sum / static_cast<double>(v.size());
  s.max = *std::max_element(v.begin(), v.end());
  size_t k = static_cast<size_t>(std::ceil(0.95 * static_cast<double>(v.size()))) - 1;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  s.p95 = v[k];
  return s;
}

MapQuality measure(const mesh::TriMesh& surface, const mesh::Vertices& image, Target target) {
  MapQuality q;
  const int nf = surface.num_faces();
  std::vector<double> angles;
  angles.reserve(static_cast<size_t>(nf) * 3);
  Eigen::VectorXd a_img(nf);
  q.qc_ratio.resize(nf);
  q.angle_distortion.resize(nf);
  for (int f = 0; f < nf; ++f) {
    Vec3 p[3], x[3];
    for (int k = 0; k < 3; ++k) {
      p[k] = surface.V.row(surface.F(f, k)).transpose();
      x[k] = image.row(surface.F(f, k)).transpose();
    }
    Vec3 n = (x[1] - x[0]).cross(x[2] - x[0]);
    a_img[f] = 0.5 * n.norm();
    bool flipped = target == Target::kPlane ? !(n.z() > 0) : !(n.dot(x[0] + x[1] + x[2]) > 0);
    if (flipped) {
      ++q.flipped_faces;
      if (q.flipped.size() < 1000) q.flipped.push_back(f);
    }
    q.angle_distortion[f] = 0;
    for (int k = 0; k < 3; ++k) {
      double d = angle(x[k], x[(k + 1) % 3], x[(k + 2) % 3]) - angle(p[k], p[(k + 1) % 3], p[(k + 2) % 3]);
      angles.push_back(std::abs(d) * 180.0 / std::numbers::pi);
      q.angle_distortion[f] = std::max(q.angle_distortion[f], angles.back());
    }
    if (flipped || !(a_img[f] > 0)) {
      q.qc_ratio[f] = std::numeric_limits<double>::infinity();
      continue;
    }
    Eigen::Matrix2d J = affine(flatten(p[0], p[1], p[2]), flatten(x[0], x[1], x[2]));
    Eigen::JacobiSVD<Eigen::Matrix2d> svd(J);
    q.qc_ratio[f] = svd.singularValues()[0] / svd.singularValues()[1];
  }
  q.angle_distortion_deg = stats(angles);
  q.area_distortion_log = area_log_ratios(surface, image);
  std::vector<double> abs_log(nf);
  for (int f = 0; f < nf; ++f) abs_log[f] = std::abs(q.area_distortion_log[f]);
  q.area_distortion_log_abs = stats(abs_log);
  std::vector<double> qc(q.qc_ratio.data(), q.qc_ratio.data() + nf);
  qc.erase(std::remove_if(qc.begin(), qc.end(), [](double v) { return !std::isfinite(v); }), qc.end());
  q.quasi_conformal = stats(qc);
  if (target == Target::kSphere) q.degree = sphere_degree(surface.F, image);
  return q;
}

double geodesic_triangle_area(const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Eigen::Vector3d& r) {
  // Van Oosterom and Strackee (1983): E = 2 atan2(a . (b x c), 1 + a.b + b.c + c.a).
  const Vec3 a = p.normalized(), b = q.normalized(), c = r.normalized();
  return 2 * std::atan2(a.dot(b.cross(c)), 1 + a.dot(b) + b.dot(c) + c.dot(a));
}

double sphere_degree(const mesh::Faces& F, const mesh::Vertices& X) {
  double sum = 0;
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    sum += geodesic_triangle_area(X.row(F(f, 0)), X.row(F(f, 1)), X.row(F(f, 2)));
  return sum / (4 * std::numbers::pi);
}

Eigen::VectorXcd beltrami(const mesh::Faces& F, const mesh::Vertices& a, const mesh::Vertices& b) {
  Eigen::VectorXcd mu(F.rows());
  for (int f = 0; f < F.rows(); ++f) {
    Vec3 p[3], x[3];
    for (int k = 0; k < 3; ++k) {
      p[k] = a.row(F(f, k)).transpose();
      x[k] = b.row(F(f, k)).transpose();
    }
    Eigen::Matrix2d J = affine(flatten(p[0], p[1], p[2]), flatten(x[0], x[1], x[2]));
    // f = J z: f_z = ((a + d) + i (c - b)) / 2, f_zbar = ((a - d) + i (c + b)) / 2.
    std::complex<double> fz(0.5 * (J(0, 0) + J(1, 1)), 0.5 * (J(1, 0) - J(0, 1)));
    std::complex<double> fzb(0.5 * (J(0, 0) - J(1, 1)), 0.5 * (J(1, 0) + J(0, 1)));
    mu[f] = fzb / fz;
  }
  return mu;
}

}  // namespace brenier::quality
