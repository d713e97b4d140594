#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <random>

#include "numeric/face_hessian.hpp"

using brenier::numeric::Dof;
using brenier::numeric::FaceHessian;

namespace {

// A k x k grid of vertices, two triangles per cell.
brenier::mesh::Faces grid_faces(int k) {
  brenier::mesh::Faces F(2 * (k - 1) * (k - 1), 3);
  int f = 0;
  for (int i = 0; i + 1 < k; ++i)
    for (int j = 0; j + 1 < k; ++j) {
      const int a = i * k + j, b = a + 1, c = a + k, d = c + 1;
      F.row(f++) << a, b, d;
      F.row(f++) << a, d, c;
    }
  return F;
}

}  // namespace

// The Hessian is stored and factored in CHOLMOD's fill-reducing order, while its callers add
// faces' blocks, read and shift diagonal entries (one by one and by the mean) and solve in their own numbering of the
// unknowns. Held vertices, vertices with one unknown and with two are mixed, and the solution
// must be the dense system's, assembled in the callers' numbering.
TEST(FaceHessian, SolvesInTheCallersNumberingWhateverTheOrdering) {
  const int k = 14;
  const brenier::mesh::Faces F = grid_faces(k);
  std::vector<char> unknowns(k * k);
  for (int v = 0; v < k * k; ++v) unknowns[v] = static_cast<char>(v % 7 == 0 ? 0 : v % 5 == 0 ? 1 : 2);
  FaceHessian H(F, unknowns);
  const std::vector<Dof>& dof = H.dof();
  const int n = H.size();
  ASSERT_GT(n, 300);
  std::mt19937 rng(7);
  std::normal_distribution<double> N(0.0, 1.0);
  Eigen::MatrixXd dense = Eigen::MatrixXd::Zero(n, n);
  H.clear();
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    FaceHessian::Mat6 A;
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < 6; ++c) A(r, c) = N(rng);
    const FaceHessian::Mat6 M = A * A.transpose();  // symmetric positive semi-definite
    H.add(f, M);
    for (int p = 0; p < 3; ++p)
      for (int q = 0; q < 3; ++q) {
        const Dof &dp = dof[F(f, p)], &dq = dof[F(f, q)];
        for (int a = 0; a < dp.count; ++a)
          for (int b = 0; b < dq.count; ++b) dense(dp.offset + a, dq.offset + b) += M(2 * p + a, 2 * q + b);
      }
  }
  for (int i = 0; i < n; ++i) {
    EXPECT_DOUBLE_EQ(H.diagonal(i), dense(i, i)) << "unknown " << i;
    const double shift = 0.5 + (i % 3);
    H.diagonal(i) += shift;
    dense(i, i) += shift;
  }
  // A shift by a fraction of the diagonal's mean (the refinements' Levenberg-Marquardt term).
  H.shift_diagonal_by_mean(0.25);
  dense.diagonal().array() += 0.25 * dense.diagonal().mean();
  for (int i = 0; i < n; ++i) EXPECT_NEAR(H.diagonal(i), dense(i, i), 1e-12 * dense(i, i)) << "unknown " << i;
  ASSERT_TRUE(H.factorize());
  Eigen::VectorXd b(n);
  for (int i = 0; i < n; ++i) b[i] = N(rng);
  const Eigen::VectorXd x = H.solve(b), truth = dense.llt().solve(b);
  EXPECT_LT((x - truth).norm() / truth.norm(), 1e-10);
  EXPECT_LT((dense * x - b).norm() / b.norm(), 1e-10);
}

// A matrix that is not positive definite is reported, not factored.
TEST(FaceHessian, RefusesAnIndefiniteMatrix) {
  const brenier::mesh::Faces F = grid_faces(4);
  FaceHessian H(F, std::vector<char>(16, 2));
  H.clear();
  for (Eigen::Index f = 0; f < F.rows(); ++f) H.add(f, FaceHessian::Mat6::Identity());
  H.diagonal(5) = -1.0;
  EXPECT_FALSE(H.factorize());
}
