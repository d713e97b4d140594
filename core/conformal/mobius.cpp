#include "conformal/mobius.hpp"

#include <cmath>

#include "common/error.hpp"

namespace brenier::conformal {

Complex disk_automorphism(Complex z, Complex a) { return (z - a) / (1.0 - std::conj(a) * z); }

void apply_disk_mobius(mesh::UV& uv, Complex a, double theta, Eigen::VectorXd* log_scale) {
  const Complex rot = std::polar(1.0, theta);
  for (int i = 0; i < uv.rows(); ++i) {
    const Complex z(uv(i, 0), uv(i, 1));
    if (log_scale)
      (*log_scale)[i] += std::log(1.0 - std::norm(a)) - 2.0 * std::log(std::abs(1.0 - std::conj(a) * z));
    Complex w = rot * disk_automorphism(z, a);
    uv(i, 0) = w.real();
    uv(i, 1) = w.imag();
  }
}

int center_disk(mesh::UV& uv, const mesh::Faces& F, const Eigen::VectorXd& area, double tol,
                int max_iterations, Eigen::VectorXd* log_scale) {
  const double total = area.sum();
  for (int it = 0; it < max_iterations; ++it) {
    Complex c = 0;
    for (int f = 0; f < F.rows(); ++f) {
      Complex p = (Complex(uv(F(f, 0), 0), uv(F(f, 0), 1)) + Complex(uv(F(f, 1), 0), uv(F(f, 1), 1)) +
                   Complex(uv(F(f, 2), 0), uv(F(f, 2), 1))) / 3.0;
      c += area[f] * p;
    }
    c /= total;
    if (std::abs(c) <= tol) return it;
    // Moving a point a to 0 moves the centre of mass by about -a; for far-off-centre masses
    // the step is damped so a stays well inside the disk.
    double r = std::abs(c);
    Complex a = r < 0.5 ? c : c * (0.5 / r);
    apply_disk_mobius(uv, a, 0.0, log_scale);
  }
  return max_iterations;
}

Eigen::Vector3d sphere_automorphism(const Eigen::Vector3d& x, const Eigen::Vector3d& a) {
  const Eigen::Vector3d d = x - a;
  return ((1 - a.squaredNorm()) * d / d.squaredNorm() - a).normalized();
}

int center_sphere(mesh::Vertices& X, const mesh::Faces& F, const Eigen::VectorXd& area, double tol,
                  int max_iterations, Eigen::VectorXd* log_scale) {
  // Vertex masses (a third of the adjacent faces' areas) at the vertices: unlike chord
  // centroids of faces, these can balance even for a coarse mesh (a tetrahedron's faces'
  // chord centroids can all lie in one hemisphere).
  Eigen::VectorXd mass = Eigen::VectorXd::Zero(X.rows());
  for (int f = 0; f < F.rows(); ++f)
    for (int k = 0; k < 3; ++k) mass[F(f, k)] += area[f] / 3.0;
  const double total = mass.sum();
  for (int it = 0; it < max_iterations; ++it) {
    Eigen::Vector3d c = (X.transpose() * mass) / total;
    if (c.norm() <= tol) return it;
    double r = c.norm();
    Eigen::Vector3d a = r < 0.5 ? c : Eigen::Vector3d(c * (0.5 / r));
    const double a2 = a.squaredNorm();
    for (int i = 0; i < X.rows(); ++i) {
      const Eigen::Vector3d x = X.row(i).transpose();
      if (log_scale) (*log_scale)[i] += std::log((1 - a2) / (x - a).squaredNorm());
      X.row(i) = sphere_automorphism(x, a).transpose();
    }
  }
  return max_iterations;
}

Complex stereographic(const Eigen::Vector3d& x) {
  double d = 1.0 - x.z();
  return Complex(x.x() / d, x.y() / d);
}

Eigen::Vector3d inverse_stereographic(Complex z) {
  double r2 = std::norm(z);
  return Eigen::Vector3d(2 * z.real(), 2 * z.imag(), r2 - 1) / (1 + r2);
}

}  // namespace brenier::conformal
