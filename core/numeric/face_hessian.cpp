#include "numeric/face_hessian.hpp"

#include <algorithm>
#include <numeric>

#include "common/check.hpp"
#include "common/parallel.hpp"

namespace brenier::numeric {

namespace {

// The lower-triangle pattern of the faces' entries, unknown i at row and column position[i].
Eigen::SparseMatrix<double> pattern(const mesh::Faces& F, const std::vector<Dof>& dof, int n,
                                    const std::vector<int>& position) {
  std::vector<Eigen::Triplet<double>> entries;
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    each_face_entry({F(f, 0), F(f, 1), F(f, 2)}, dof, [&](int, int r, int c) {
      const int pr = position[static_cast<size_t>(r)], pc = position[static_cast<size_t>(c)];
      entries.emplace_back(std::max(pr, pc), std::min(pr, pc), 1.0);
    });
  Eigen::SparseMatrix<double> H(n, n);
  H.setFromTriplets(entries.begin(), entries.end());
  H.makeCompressed();
  return H;
}

// The value index of entry (r, c) of a compressed lower triangle, r >= c.
int slot_of(const Eigen::SparseMatrix<double>& H, int r, int c) {
  const int* rows = H.innerIndexPtr();
  const int* begin = rows + H.outerIndexPtr()[c];
  const int* end = rows + H.outerIndexPtr()[c + 1];
  const int* at = std::lower_bound(begin, end, r);
  BRENIER_CHECK(at != end && *at == r, "entry (" << r << ", " << c << ") is not in the Hessian's pattern");
  return static_cast<int>(at - rows);
}

// CHOLMOD's fill-reducing ordering of the lower triangle H (nested dissection, postordered):
// unknown k of the result's numbering is unknown order[k] of H's.
std::vector<int> fill_reducing_order(const Eigen::SparseMatrix<double>& H, cholmod_common& c) {
  c.nmethods = 1;
  c.method[0].ordering = CHOLMOD_NESDIS;
  const int mode = c.supernodal;
  c.supernodal = CHOLMOD_SIMPLICIAL;  // the ordering only: no supernodal symbolic pass
  cholmod_sparse A = Eigen::viewAsCholmod(H.selfadjointView<Eigen::Lower>());
  cholmod_factor* L = cholmod_analyze(&A, &c);
  c.supernodal = mode;
  BRENIER_CHECK(L != nullptr, "CHOLMOD could not order the Hessian (status " << c.status << ")");
  const int* perm = static_cast<const int*>(L->Perm);
  std::vector<int> order(perm, perm + H.rows());
  cholmod_free_factor(&L, &c);
  return order;
}

}  // namespace

FaceHessian::FaceHessian(const mesh::Faces& F, const std::vector<char>& unknowns) : dof_(unknowns.size()) {
  for (size_t r = 0; r < unknowns.size(); ++r)
    if (unknowns[r] > 0) dof_[r] = {n_, unknowns[r]}, n_ += unknowns[r];
  single_threaded_blas();  // before CHOLMOD reaches OpenBLAS
  llt_.setMode(Eigen::CholmodSupernodalLLt);
  cholmod_common& c = llt_.cholmod();
  c.print = 0;
  position_.resize(static_cast<size_t>(n_));
  std::iota(position_.begin(), position_.end(), 0);
  if (n_ > 0) {
    const Eigen::SparseMatrix<double> unordered = pattern(F, dof_, n_, position_);
    const std::vector<int> order = fill_reducing_order(unordered, c);
    for (int k = 0; k < n_; ++k) position_[static_cast<size_t>(order[static_cast<size_t>(k)])] = k;
  }
  H_ = pattern(F, dof_, n_, position_);
  auto slot = [this](int r, int c) {
    const int pr = position_[static_cast<size_t>(r)], pc = position_[static_cast<size_t>(c)];
    return slot_of(H_, std::max(pr, pc), std::min(pr, pc));
  };
  slots_.assign(static_cast<size_t>(F.rows()) * 36, -1);
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    each_face_entry({F(f, 0), F(f, 1), F(f, 2)}, dof_, [&](int local, int r, int c) {
      slots_[static_cast<size_t>(f) * 36 + static_cast<size_t>(local)] = slot(r, c);
    });
  diagonal_.resize(static_cast<size_t>(n_));
  for (int i = 0; i < n_; ++i) diagonal_[static_cast<size_t>(i)] = slot(i, i);
  // The matrix is in the ordering's order already: analysed as it stands, and not postordered
  // again (CHOLMOD would then record a permutation and transpose at every factorization).
  c.nmethods = 1;
  c.method[0].ordering = CHOLMOD_NATURAL;
  c.postorder = 0;
  if (n_ > 0) llt_.analyzePattern(H_);
}

void FaceHessian::clear() { std::fill(H_.valuePtr(), H_.valuePtr() + H_.nonZeros(), 0.0); }

void FaceHessian::add(Eigen::Index f, const Mat6& H) {
  double* values = H_.valuePtr();
  const int* slots = slots_.data() + static_cast<size_t>(f) * 36;
  for (int e = 0; e < 36; ++e)
    if (slots[e] >= 0) values[slots[e]] += H(e % 6, e / 6);
}

bool FaceHessian::factorize() {
  BRENIER_CHECK(n_ > 0, "a Hessian without unknowns was factored");
  with_library_loops_serial([&] { llt_.factorize(H_); });
  return llt_.info() == Eigen::Success;
}

void FaceHessian::shift_diagonal_by_mean(double fraction) {
  double trace = 0;
  for (int i = 0; i < n_; ++i) trace += diagonal(i);
  const double shift = fraction * trace / n_;
  for (int i = 0; i < n_; ++i) diagonal(i) += shift;
}

Eigen::VectorXd FaceHessian::solve(const Eigen::VectorXd& b) const {
  Eigen::VectorXd permuted(n_);
  for (int i = 0; i < n_; ++i) permuted[position_[static_cast<size_t>(i)]] = b[i];
  const Eigen::VectorXd x = llt_.solve(permuted);
  Eigen::VectorXd out(n_);
  for (int i = 0; i < n_; ++i) out[i] = x[position_[static_cast<size_t>(i)]];
  return out;
}

}  // namespace brenier::numeric
