// The barrier energy of fold_repair.hpp, shared by the fold repair and the area refinement
// (area_refinement.hpp): per face with Jacobian J against a reference triangle of the face's
// target area, a [theta (det J^2 + 1) + (1 - theta) |J|_F^2] / chi(det J, eps), on the unit
// sphere (SphereBarrier) or in a plane (PlaneBarrier), and its L-BFGS untangling.
// Internal to core/omt.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <LBFGS.h>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::omt::detail {

struct BarrierFace {
  std::array<int, 3> v;     // indices into the positions, counter-clockwise in the reference
  Eigen::Matrix2d ref_inv;  // inverse of [q1 - q0, q2 - q0] of the reference triangle
  double weight = 0;        // the reference triangle's area
};

// The reference triangle of a face with 3-D corners a, b, c, scaled to area `area`.
inline BarrierFace barrier_face(int i, int j, int k, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                         const Eigen::Vector3d& c, double area) {
  // The face in its own plane: q0 = 0, q1 on the first axis, q2 above it (counter-clockwise).
  const Eigen::Vector3d e = b - a, g = c - a;
  const double len = e.norm();
  const Eigen::Vector3d u = e / len, n = e.cross(g);
  const Eigen::Vector3d w = n.normalized().cross(u);
  Eigen::Matrix2d Q;
  Q << len, g.dot(u), 0, g.dot(w);
  Q *= std::sqrt(area / (0.5 * n.norm()));  // scaled to the target area
  BarrierFace f;
  f.v = {i, j, k};
  f.ref_inv = Q.inverse();
  f.weight = area;
  return f;
}

// One face's term of the energy of fold_repair.hpp, a [theta (D^2 + 1) + (1 - theta) |J|_F^2]
// / chi(D, eps), for the Jacobian J = M ref_inv of its edge matrix M (chord edges on the
// sphere, chart edges in the plane) and its area ratio D; sets its derivatives in D and in M.
template <int Rows>
double barrier_term(const BarrierFace& f, const Eigen::Matrix<double, Rows, 2>& M, double D, double theta,
                    double eps, double& dE_dD, Eigen::Matrix<double, Rows, 2>& dE_dM) {
  const Eigen::Matrix<double, Rows, 2> J = M * f.ref_inv;
  const double T = J.squaredNorm();
  const double s = std::sqrt(eps * eps + D * D), chi = 0.5 * (D + s), dchi = 0.5 * (1 + D / s);
  const double num = theta * (D * D + 1) + (1 - theta) * T;
  dE_dD = f.weight * (theta * 2 * D / chi - num * dchi / (chi * chi));
  dE_dM = f.weight * (1 - theta) * 2 / chi * J * f.ref_inv.transpose();
  return f.weight * num / chi;
}

// The energy over the free vertices on the sphere, for L-BFGS. A free vertex is x = y / |y|
// for unknowns y in R^3, so every trial point lies on the sphere. The face's signed area
// is read as det(a, b, c) / 2 (the chord triangle's area times its plane's distance from
// the centre: positive exactly when it faces outward, the fold test), so
// D = det(a, b, c) / (2 A_target); |J|_F^2 is that of the chord triangle's edges against
// the reference's.
struct SphereBarrier {
  static constexpr int kDim = 3;
  const std::vector<BarrierFace>& faces;
  mesh::Vertices& X;
  const std::vector<int>& var;   // row of X -> its first unknown, or -1 when fixed
  const std::vector<int>& rows;  // the free rows, in the unknowns' order
  double theta, eps = 1;
  double min_det = 0;

  void load(const Eigen::VectorXd& y) {
    for (int r : rows) X.row(r) = y.segment<3>(var[r]).normalized().transpose();
  }
  Eigen::Vector3d at(int r) const { return X.row(r).transpose(); }
  bool facing(const BarrierFace& f) const { return at(f.v[0]).dot(at(f.v[1]).cross(at(f.v[2]))) > 0; }
  double operator()(const Eigen::VectorXd& y, Eigen::VectorXd& grad) {
    load(y);
    grad.setZero(y.size());
    Eigen::VectorXd gx = Eigen::VectorXd::Zero(y.size());  // gradient in x
    double E = 0;
    min_det = std::numeric_limits<double>::infinity();
    for (const BarrierFace& f : faces) {
      const Eigen::Vector3d a = at(f.v[0]), b = at(f.v[1]), c = at(f.v[2]);
      Eigen::Matrix<double, 3, 2> M, dM;
      M << b - a, c - a;
      const double D = a.dot(b.cross(c)) / (2 * f.weight);
      min_det = std::min(min_det, D);
      double dD;
      E += barrier_term(f, M, D, theta, eps, dD, dM);
      dD /= 2 * f.weight;
      auto add = [&](int row, const Eigen::Vector3d& d) {
        if (var[row] >= 0) gx.segment<3>(var[row]) += d;
      };
      add(f.v[0], dD * b.cross(c) - dM.col(0) - dM.col(1));
      add(f.v[1], dD * c.cross(a) + dM.col(0));
      add(f.v[2], dD * a.cross(b) + dM.col(1));
    }
    for (int r : rows) {  // through x = y / |y|: (I - x x^T) g / |y|
      const Eigen::Vector3d x = at(r), g = gx.segment<3>(var[r]);
      grad.segment<3>(var[r]) = (g - x * x.dot(g)) / y.segment<3>(var[r]).norm();
    }
    return E;
  }
};

// The same energy in a planar chart (rows of X are chart points, z = 0): D = det M / (2 A),
// positive exactly when the face turns counter-clockwise.
struct PlaneBarrier {
  static constexpr int kDim = 2;
  const std::vector<BarrierFace>& faces;
  mesh::Vertices& X;
  const std::vector<int>& var;
  const std::vector<int>& rows;
  double theta, eps = 1;
  double min_det = 0;

  void load(const Eigen::VectorXd& y) {
    for (int r : rows) X.row(r).head<2>() = y.segment<2>(var[r]).transpose();
  }
  Eigen::Vector2d at(int r) const { return X.row(r).head<2>().transpose(); }
  static double cross(const Eigen::Vector2d& u, const Eigen::Vector2d& w) { return u.x() * w.y() - u.y() * w.x(); }
  bool facing(const BarrierFace& f) const { return cross(at(f.v[1]) - at(f.v[0]), at(f.v[2]) - at(f.v[0])) > 0; }
  double operator()(const Eigen::VectorXd& y, Eigen::VectorXd& grad) {
    load(y);
    grad.setZero(y.size());
    double E = 0;
    min_det = std::numeric_limits<double>::infinity();
    for (const BarrierFace& f : faces) {
      const Eigen::Vector2d a = at(f.v[0]), b = at(f.v[1]), c = at(f.v[2]);
      Eigen::Matrix2d M, dM;
      M << b - a, c - a;
      const double D = cross(b - a, c - a) / (2 * f.weight);
      min_det = std::min(min_det, D);
      double dD;
      E += barrier_term(f, M, D, theta, eps, dD, dM);
      dD /= 2 * f.weight;
      // d cross(b - a, c - a) / db = perp(c - a), / dc = -perp(b - a), perp(u) = (u.y, -u.x)
      const Eigen::Vector2d db(c.y() - a.y(), a.x() - c.x()), dc(a.y() - b.y(), b.x() - a.x());
      auto add = [&](int row, const Eigen::Vector2d& d) {
        if (var[row] >= 0) grad.segment<2>(var[row]) += d;
      };
      add(f.v[0], -dD * (db + dc) - dM.col(0) - dM.col(1));
      add(f.v[1], dD * db + dM.col(0));
      add(f.v[2], dD * dc + dM.col(1));
    }
    return E;
  }
};

// Moves the rows of X with free[row] != 0 to minimize the energy over `faces` (on the unit
// sphere with SphereBarrier, in a plane with PlaneBarrier); theta weighs the area term.
// Returns the number of `faces` still folded (0 on success).
template <class Energy>
int untangle_by_barrier(const std::vector<BarrierFace>& faces, mesh::Vertices& X, const std::vector<char>& free,
                        double theta = 0.9) {
  constexpr int d = Energy::kDim;
  std::vector<int> var(X.rows(), -1), rows;
  int n = 0;
  for (Eigen::Index r = 0; r < X.rows(); ++r)
    if (free[r]) var[r] = n, n += d, rows.push_back(static_cast<int>(r));
  Energy energy{faces, X, var, rows, theta};
  Eigen::VectorXd y(n), grad(n);
  for (int r : rows) y.segment<d>(var[r]) = X.row(r).head<d>().transpose();
  energy.eps = 1;
  energy(y, grad);
  // eps from the smallest det J: chi(min det, eps) = mu, i.e. eps = 2 sqrt(mu (mu - min det)),
  // mu shrinking with the energy's relative decrease (the paper's schedule).
  auto eps_for = [](double mu, double det) { return det < mu ? 2 * std::sqrt(mu * (mu - det)) : 1e-12; };
  energy.eps = eps_for(0.1, energy.min_det);
  LBFGSpp::LBFGSParam<double> param;
  param.epsilon = 1e-9;
  param.max_iterations = 400;
  param.max_linesearch = 40;
  for (int outer = 0; outer < 60; ++outer) {
    const double E_prev = energy(y, grad);
    const Eigen::VectorXd y_prev = y;
    LBFGSpp::LBFGSSolver<double> solver(param);
    double fx = E_prev;
    try {
      solver.minimize(energy, y, fx);
    } catch (const std::exception&) {
      // A line search that cannot lower the energy further throws, with y left at its last
      // trial point, which may be worse than where it started (a face turned over with eps
      // tiny makes the energy infinite, or NaN): then y goes back.
      if (!(energy(y, grad) <= E_prev)) y = y_prev;
    }
    const double E = energy(y, grad);
    if (energy.min_det > 0 && outer > 0 && energy.eps < 1e-9) break;
    const double sigma = std::max(1 - E / E_prev, 0.1);
    const double s = std::sqrt(energy.eps * energy.eps + energy.min_det * energy.min_det);
    const double mu = (1 - sigma) * 0.5 * (energy.min_det + s);
    energy.eps = eps_for(mu, energy.min_det);
  }
  energy(y, grad);
  int folds = 0;
  for (const BarrierFace& f : faces) folds += !energy.facing(f);
  return folds;
}

}  // namespace brenier::omt::detail
