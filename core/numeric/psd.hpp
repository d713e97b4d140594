// Projections of symmetric matrices onto the positive semi-definite cone, for projected Newton
// methods (Teran et al. 2005): each element's Hessian with its negative eigenvalues set to zero.
#pragma once

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

namespace brenier::numeric {

/// The symmetric matrix H with its negative eigenvalues set to zero (an eigendecomposition).
template <int N>
Eigen::Matrix<double, N, N> clamped(const Eigen::Matrix<double, N, N>& H) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, N, N>> eig(H);
  return eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).asDiagonal() * eig.eigenvectors().transpose();
}

/// The gradient and Hessian in vec J = (J00, J10, J01, J11) of an energy psi(D, T) of a 2x2 J,
/// D = det J, T = |J|_F^2, from psi's partial derivatives (eTT = 0: the refinement's energy):
///   g = psi_D cof J + psi_T 2 vec J,
///   H = psi_DD c c^T + psi_DT (c t^T + t c^T) + psi_D d^2 D + 2 psi_T I + psi_TT t t^T,
/// c = cof J = dD / d vec J, t = dT / d vec J, d^2 D the constant [0 0 0 1; 0 0 -1 0; ...].
struct IsotropicDerivatives2d {
  Eigen::Vector4d g;
  Eigen::Matrix4d H;
};
inline IsotropicDerivatives2d isotropic_derivatives_2d(const Eigen::Matrix2d& J, double eD, double eT, double eDD,
                                                       double eDT, double eTT = 0) {
  const Eigen::Vector4d j(J(0, 0), J(1, 0), J(0, 1), J(1, 1));
  const Eigen::Vector4d cof(J(1, 1), -J(0, 1), -J(1, 0), J(0, 0));
  Eigen::Matrix4d HD = Eigen::Matrix4d::Zero();
  HD(0, 3) = HD(3, 0) = 1;
  HD(1, 2) = HD(2, 1) = -1;
  const Eigen::Vector4d gT = 2 * j;
  IsotropicDerivatives2d d{eD * cof + eT * gT, eDD * cof * cof.transpose() +
                                                   eDT * (cof * gT.transpose() + gT * cof.transpose()) + eD * HD +
                                                   2 * eT * Eigen::Matrix4d::Identity()};
  if (eTT != 0) d.H += eTT * gT * gT.transpose();
  return d;
}

/// The same projection, in closed form, for H the Hessian in vec J = (J00, J10, J01, J11) of
/// an energy of a 2x2 J that depends on J's singular values alone (such as one of det J and
/// |J|_F^2), det J > 0. Such an energy does not change under J -> R1 J R2 (R1, R2 rotations),
/// and its Hessian is block diagonal in the orthonormal basis (Smith, de Goes and Kim 2019,
/// "Analytic eigensystems for isotropic distortion energies", in 2-D):
///   w, the rotation of J's polar decomposition, and a, J's anti-conformal part's direction
///      (together they span J's two scaling modes): a 2x2 block;
///   t = R90 w (the twist) and f, a's normal in the anti-conformal plane (the flip):
///      eigenvectors of their own.
/// J = E I + K R90 + F P + G S with I, R90 = [0 -1; 1 0], P = [1 0; 0 -1], S = [0 1; 1 0], so
/// w ~ E I + K R90, t ~ E R90 - K I, a ~ F P + G S, f ~ F S - G P. Where J is conformal (F = G
/// = 0) any orthonormal pair of the anti-conformal plane serves: P and S. The 2x2 block is
/// clamped in closed form. An eighth of the eigensolver's cost: 0.11 against 0.8-0.9 us a call
/// on the refinement's Hessians (bench/bench_psd.cpp; bench/RESULTS.md, session 47).
inline Eigen::Matrix4d clamped_isotropic_2d(const Eigen::Matrix2d& J, const Eigen::Matrix4d& H) {
  const double E = 0.5 * (J(0, 0) + J(1, 1)), K = 0.5 * (J(1, 0) - J(0, 1));
  const double F = 0.5 * (J(0, 0) - J(1, 1)), G = 0.5 * (J(1, 0) + J(0, 1));
  const double q = std::hypot(E, K), r = std::hypot(F, G);
  if (!(q > r)) return clamped<4>(H);  // det J = q^2 - r^2 <= 0: not the case this is for
  const double c = E / q, s = K / q;
  const double cf = r > 0 ? F / r : 1.0, sg = r > 0 ? G / r : 0.0;
  const double k = std::sqrt(0.5);
  Eigen::Matrix4d B;  // columns w, a, t, f as vec of 2x2 matrices (column-major)
  B.col(0) << c, s, -s, c;
  B.col(1) << cf, sg, sg, -cf;
  B.col(2) << -s, c, -c, -s;
  B.col(3) << -sg, cf, cf, sg;
  B *= k;
  const Eigen::Matrix4d M = B.transpose() * H * B;
  Eigen::Matrix4d P = Eigen::Matrix4d::Zero();
  // The 2x2 block [p o; o u]: eigenvalues m +- d.
  const double p = M(0, 0), o = 0.5 * (M(0, 1) + M(1, 0)), u = M(1, 1);
  const double m = 0.5 * (p + u), d = std::hypot(0.5 * (p - u), o);
  if (m - d >= 0) {
    P(0, 0) = p, P(0, 1) = P(1, 0) = o, P(1, 1) = u;
  } else if (m + d > 0) {
    // Only the larger eigenvalue m + d stays, with its eigenvector: (o, m + d - p) or
    // (m + d - u, o), whichever is longer (one of them can vanish).
    Eigen::Vector2d v1(o, m + d - p), v2(m + d - u, o);
    Eigen::Vector2d v = v1.squaredNorm() >= v2.squaredNorm() ? v1 : v2;
    v.normalize();
    P.topLeftCorner<2, 2>() = (m + d) * v * v.transpose();
  }
  P(2, 2) = std::max(M(2, 2), 0.0);
  P(3, 3) = std::max(M(3, 3), 0.0);
  return B * P * B.transpose();
}

}  // namespace brenier::numeric
