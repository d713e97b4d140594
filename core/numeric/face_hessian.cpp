#include "numeric/face_hessian.hpp"

#include <algorithm>

#include "common/check.hpp"
#include "common/parallel.hpp"

namespace brenier::numeric {

FaceHessian::FaceHessian(const mesh::Faces& F, const std::vector<char>& unknowns) : dof_(unknowns.size()) {
  for (size_t r = 0; r < unknowns.size(); ++r)
    if (unknowns[r] > 0) dof_[r] = {n_, unknowns[r]}, n_ += unknowns[r];
  auto corners = [&F](Eigen::Index f) { return std::array<int, 3>{F(f, 0), F(f, 1), F(f, 2)}; };
  std::vector<Eigen::Triplet<double>> entries;
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    each_face_entry(corners(f), dof_, [&](int, int r, int c) { entries.emplace_back(r, c, 1.0); });
  H_.resize(n_, n_);
  H_.setFromTriplets(entries.begin(), entries.end());
  H_.makeCompressed();
  slots_.assign(static_cast<size_t>(F.rows()) * 36, -1);
  for (Eigen::Index f = 0; f < F.rows(); ++f)
    each_face_entry(corners(f), dof_, [&](int local, int r, int c) {
      const int* rows = H_.innerIndexPtr();
      const int* begin = rows + H_.outerIndexPtr()[c];
      const int* end = rows + H_.outerIndexPtr()[c + 1];
      slots_[static_cast<size_t>(f) * 36 + static_cast<size_t>(local)] = static_cast<int>(std::lower_bound(begin, end, r) - rows);
    });
  single_threaded_blas();  // before CHOLMOD reaches OpenBLAS
  llt_.setMode(Eigen::CholmodSupernodalLLt);
  llt_.cholmod().print = 0;
  llt_.cholmod().nmethods = 1;
  llt_.cholmod().method[0].ordering = CHOLMOD_NESDIS;
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

Eigen::VectorXd FaceHessian::solve(const Eigen::VectorXd& b) const { return llt_.solve(b); }

}  // namespace brenier::numeric
