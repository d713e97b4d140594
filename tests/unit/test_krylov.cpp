#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <random>

#include "numeric/krylov.hpp"

using brenier::numeric::gmres;
using brenier::numeric::LinearOperator;

namespace {

Eigen::MatrixXd random_matrix(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> N(0.0, 1.0);
  Eigen::MatrixXd A(n, n);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) A(i, j) = N(rng);
  return A;
}

LinearOperator times(const Eigen::MatrixXd& A) {
  return [&A](const Eigen::VectorXd& x) { return Eigen::VectorXd(A * x); };
}

const LinearOperator kIdentity = [](const Eigen::VectorXd& x) { return x; };

}  // namespace

TEST(Gmres, SymmetricIndefiniteSystemToTolerance) {
  // A symmetric matrix with eigenvalues of both signs: CG would fail, GMRES must not.
  const int n = 60;
  Eigen::MatrixXd Q = random_matrix(n, 1).householderQr().householderQ();
  Eigen::VectorXd lambda = Eigen::VectorXd::LinSpaced(n, -3.0, 5.0);
  lambda[n / 2] = 0.7;  // keep 0 out of the spectrum
  Eigen::MatrixXd A = Q * lambda.asDiagonal() * Q.transpose();
  Eigen::VectorXd truth = Eigen::VectorXd::LinSpaced(n, -1.0, 2.0);
  Eigen::VectorXd b = A * truth, x;
  auto r = gmres(times(A), kIdentity, b, x, 1e-12, 200, 80);
  ASSERT_TRUE(r.converged) << r.relative_residual;
  EXPECT_LE(r.iterations, n);  // exact arithmetic: at most n steps without restart
  EXPECT_LE((b - A * x).norm() / b.norm(), 1e-12);  // the reported residual is the true one
  EXPECT_NEAR(r.relative_residual, (b - A * x).norm() / b.norm(), 1e-14);
  EXPECT_LT((x - truth).norm() / truth.norm(), 1e-9);
}

TEST(Gmres, ExactPreconditionerConvergesInOneStep) {
  const int n = 40;
  Eigen::MatrixXd A = random_matrix(n, 2) + n * Eigen::MatrixXd::Identity(n, n);
  Eigen::PartialPivLU<Eigen::MatrixXd> lu(A);
  LinearOperator inverse = [&lu](const Eigen::VectorXd& x) { return Eigen::VectorXd(lu.solve(x)); };
  Eigen::VectorXd b = Eigen::VectorXd::Ones(n), x;
  auto r = gmres(times(A), inverse, b, x, 1e-12, 10);
  ASSERT_TRUE(r.converged);
  EXPECT_EQ(r.iterations, 1);
  EXPECT_LT((A * x - b).norm(), 1e-10);
}

TEST(Gmres, RestartsAndStartingGuessAndBudget) {
  // A non-symmetric, well-conditioned system solved with short restarts from a guess.
  const int n = 80;
  Eigen::MatrixXd A = 0.3 * random_matrix(n, 3) / std::sqrt(n) + Eigen::MatrixXd::Identity(n, n);
  Eigen::VectorXd truth = Eigen::VectorXd::Random(n);
  Eigen::VectorXd b = A * truth;
  Eigen::VectorXd x = truth + 1e-3 * Eigen::VectorXd::Ones(n);
  auto r = gmres(times(A), kIdentity, b, x, 1e-10, 500, 5);
  ASSERT_TRUE(r.converged);
  EXPECT_LT((x - truth).norm(), 1e-8);
  // A budget too small for the tolerance: not converged, and says so.
  Eigen::VectorXd y;
  auto s = gmres(times(A), kIdentity, b, y, 1e-14, 2, 2);
  EXPECT_FALSE(s.converged);
  EXPECT_LE(s.iterations, 2);
  EXPECT_GT(s.relative_residual, 1e-14);
  EXPECT_LT(s.relative_residual, 1.0);  // but it did reduce the residual
  // b = 0: x = 0 at once.
  Eigen::VectorXd z = Eigen::VectorXd::Ones(n);
  EXPECT_TRUE(gmres(times(A), kIdentity, Eigen::VectorXd::Zero(n), z, 1e-12, 10).converged);
  EXPECT_EQ(z.norm(), 0.0);
}
