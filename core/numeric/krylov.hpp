// Krylov solvers for the Newton systems of the conformal and transport solvers.
#pragma once

#include <Eigen/Core>
#include <functional>

namespace brenier::numeric {

/// y = Op(x) for a linear operator (a matrix, a matrix plus a low-rank term, a solve).
using LinearOperator = std::function<Eigen::VectorXd(const Eigen::VectorXd&)>;

struct KrylovResult {
  int iterations = 0;            // operator applications
  double relative_residual = 0;  // |b - A x| / |b| (the true residual, not a preconditioned one)
  bool converged = false;
};

/// Restarted GMRES (Saad and Schultz) with right preconditioning: minimizes |b - A x| over
/// x0 + P^{-1} K_m, so the reported residual is the true one, which is what an inexact
/// Newton method needs; A may be indefinite and non-symmetric. Stops when
/// |b - A x| <= rtol |b| or after max_iterations applications of A. `x` holds the starting
/// guess and receives the solution.
KrylovResult gmres(const LinearOperator& A, const LinearOperator& preconditioner,
                   const Eigen::VectorXd& b, Eigen::VectorXd& x, double rtol, int max_iterations,
                   int restart = 40);

}  // namespace brenier::numeric
