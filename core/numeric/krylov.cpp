#include "numeric/krylov.hpp"

#include <Eigen/Dense>
#include <cmath>
#include <vector>

namespace brenier::numeric {

KrylovResult gmres(const LinearOperator& A, const LinearOperator& preconditioner,
                   const Eigen::VectorXd& b, Eigen::VectorXd& x, double rtol, int max_iterations,
                   int restart) {
  KrylovResult out;
  const double bnorm = b.norm();
  if (x.size() != b.size()) x = Eigen::VectorXd::Zero(b.size());
  if (bnorm == 0) {
    x.setZero();
    out.converged = true;
    return out;
  }
  const int m = std::max(1, restart);
  const double target = rtol * bnorm;
  Eigen::VectorXd r = b - A(x);
  double beta = r.norm();
  out.relative_residual = beta / bnorm;
  while (true) {
    if (beta <= target) {
      out.converged = true;
      return out;
    }
    if (out.iterations >= max_iterations || !std::isfinite(beta)) return out;
    // Arnoldi on A P^{-1} with modified Gram-Schmidt; Z keeps the preconditioned directions
    // so that the update needs no further solve. Givens rotations keep the small
    // least-squares problem triangular, and |s| is the residual norm at every step.
    std::vector<Eigen::VectorXd> V{r / beta}, Z;
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m + 1, m);
    Eigen::VectorXd cs = Eigen::VectorXd::Zero(m), sn = Eigen::VectorXd::Zero(m);
    Eigen::VectorXd s = Eigen::VectorXd::Zero(m + 1);
    s[0] = beta;
    int j = 0;
    for (; j < m && out.iterations < max_iterations; ++j) {
      Z.push_back(preconditioner(V[j]));
      Eigen::VectorXd w = A(Z[j]);
      ++out.iterations;
      for (int i = 0; i <= j; ++i) {
        H(i, j) = w.dot(V[i]);
        w -= H(i, j) * V[i];
      }
      H(j + 1, j) = w.norm();
      for (int i = 0; i < j; ++i) {  // earlier rotations on the new column
        double t = cs[i] * H(i, j) + sn[i] * H(i + 1, j);
        H(i + 1, j) = -sn[i] * H(i, j) + cs[i] * H(i + 1, j);
        H(i, j) = t;
      }
      double h = std::hypot(H(j, j), H(j + 1, j));
      bool breakdown = !(H(j + 1, j) > 1e-300 * std::max(1.0, h));
      if (!breakdown) V.push_back(w / H(j + 1, j));
      cs[j] = h > 0 ? H(j, j) / h : 1.0;
      sn[j] = h > 0 ? H(j + 1, j) / h : 0.0;
      H(j, j) = h;
      H(j + 1, j) = 0;
      s[j + 1] = -sn[j] * s[j];
      s[j] = cs[j] * s[j];
      if (std::abs(s[j + 1]) <= target || breakdown) {
        ++j;
        break;
      }
    }
    // x += Z y with H(0:j, 0:j) y = s(0:j).
    Eigen::VectorXd y = H.topLeftCorner(j, j).triangularView<Eigen::Upper>().solve(s.head(j));
    for (int i = 0; i < j; ++i) x += y[i] * Z[i];
    r = b - A(x);
    double next = r.norm();
    out.relative_residual = next / bnorm;
    if (!(next < beta) && next > target) return out;  // stagnation (or breakdown without progress)
    beta = next;
  }
}

}  // namespace brenier::numeric
