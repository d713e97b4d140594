// A symmetric Hessian over unknowns that sit on a mesh's vertices (none, one or two per
// vertex) and couple through the faces: its sparsity is the faces' corner pairs, fixed for the
// life of a solver, so the pattern, each face's value slots and CHOLMOD's ordering are made
// once and every Newton step only adds numbers. Shared by the area refinement
// (omt/area_refinement.cpp) and the isometric refinement of registrations
// (register/isometric_refine.cpp).
#pragma once

#include <Eigen/CholmodSupport>
#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <array>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::numeric {

/// A vertex's unknowns: none (held), one (a step along a curve, such as a disk's boundary
/// circle) or two (its coordinates in a chart).
struct Dof {
  int offset = -1;  // first unknown, -1: held
  int count = 0;    // 0, 1 or 2
};

/// visit(e, row, col) for the lower-triangle entries of face (a, b, c)'s Hessian between
/// unknowns, e the column-major index into its reduced 6x6 Hessian (unknown k of corner p at
/// 2p + k).
template <class Visit>
void each_face_entry(const std::array<int, 3>& v, const std::vector<Dof>& dof, const Visit& visit) {
  for (int p = 0; p < 3; ++p)
    for (int q = 0; q < 3; ++q) {
      const Dof &dp = dof[v[p]], &dq = dof[v[q]];
      for (int a = 0; a < dp.count; ++a)
        for (int b = 0; b < dq.count; ++b)
          if (dp.offset + a >= dq.offset + b) visit((2 * p + a) + 6 * (2 * q + b), dp.offset + a, dq.offset + b);
    }
}

/// The Hessian's pattern (lower triangle), its slots, and a supernodal Cholesky factor analysed
/// for it with nested dissection (the pattern is analysed once and factored at every step:
/// CHOLMOD's NESDIS left 13.7M entries in the 100K-vertex disk map's factor against AMD's
/// 17.1M; bench/RESULTS.md, session 26). Supernodal at every size: the 2x2 blocks of each
/// vertex fill more than a graph Laplacian does (session 46).
/// The matrix is stored already permuted by the analysis's ordering (NESDIS, then CHOLMOD's
/// postorder), and the factor is analysed for it in its natural order. Given a lower triangle
/// and an ordering, CHOLMOD's supernodal factorization first builds the permuted matrix by two
/// transposes (cholmod_factorize: triu(PAP'), then its transpose); in the natural order it
/// reads the lower triangle as it stands. The unknowns keep their numbering outside: add()
/// writes through the slots, diagonal() and solve() map it.
class FaceHessian {
 public:
  using Factor = Eigen::CholmodDecomposition<Eigen::SparseMatrix<double>>;
  using Mat6 = Eigen::Matrix<double, 6, 6>;

  /// `unknowns[v]`: vertex v's count (0, 1 or 2); offsets follow vertex order.
  FaceHessian(const mesh::Faces& F, const std::vector<char>& unknowns);
  FaceHessian(const FaceHessian&) = delete;
  FaceHessian& operator=(const FaceHessian&) = delete;

  int size() const { return n_; }
  const std::vector<Dof>& dof() const { return dof_; }

  /// Zeroes every value (the pattern stays).
  void clear();
  /// Adds face f's reduced 6x6 Hessian (lower triangle read) into its slots. Not thread-safe:
  /// faces sharing a vertex share slots.
  void add(Eigen::Index f, const Mat6& H);
  /// The diagonal entry of unknown i (the callers' numbering), for terms the faces do not give.
  double& diagonal(int i) { return H_.valuePtr()[diagonal_[static_cast<size_t>(i)]]; }
  /// Adds `fraction` of the diagonal's mean to every diagonal entry (a Levenberg-Marquardt
  /// shift that keeps a clamped or rank-deficient Hessian definite); the mean is summed in
  /// the callers' numbering.
  void shift_diagonal_by_mean(double fraction);
  /// Factors the current values with the library's loops on this thread; false when the
  /// matrix is not positive definite.
  bool factorize();
  /// The solution of H x = b with the last factor.
  Eigen::VectorXd solve(const Eigen::VectorXd& b) const;

 private:
  std::vector<Dof> dof_;
  int n_ = 0;
  std::vector<int> position_;  // per unknown, its row and column in H_ (the ordering's inverse)
  Eigen::SparseMatrix<double> H_;  // lower triangle, permuted
  std::vector<int> slots_;     // per face, 36 entries: the value index of each Hessian entry (-1: none)
  std::vector<int> diagonal_;  // per unknown, the value index of its diagonal entry
  Factor llt_;
};

}  // namespace brenier::numeric
