#include "distance/analysis.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>

#include "common/error.hpp"

namespace brenier::distance {

Embedding classical_mds(const Eigen::MatrixXd& d, int dims) {
  const int n = static_cast<int>(d.rows());
  if (d.cols() != n || n < 2) invalid("MDS needs a square matrix of at least two shapes");
  if (dims < 1 || dims > n) invalid("MDS: dimensions must lie in [1, " + std::to_string(n) + "]");
  const Eigen::MatrixXd J = Eigen::MatrixXd::Identity(n, n) - Eigen::MatrixXd::Constant(n, n, 1.0 / n);
  const Eigen::MatrixXd B = -0.5 * J * d.cwiseAbs2() * J;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(0.5 * (B + B.transpose()));
  if (eig.info() != Eigen::Success) fail(ErrorCode::kNotConverged, "MDS: the eigenvalue solver did not converge");
  // Eigen sorts ascending; we want descending.
  const Eigen::VectorXd values = eig.eigenvalues().reverse();
  const Eigen::MatrixXd vectors = eig.eigenvectors().rowwise().reverse();
  Embedding e;
  e.eigenvalues = values;
  e.coordinates.resize(n, dims);
  for (int c = 0; c < dims; ++c) {
    Eigen::VectorXd v = vectors.col(c);
    // Sign convention: the entry of largest magnitude positive (the same picture every run).
    Eigen::Index at = 0;
    v.cwiseAbs().maxCoeff(&at);
    if (v[at] < 0) v = -v;
    e.coordinates.col(c) = v * std::sqrt(std::max(0.0, values[c]));
  }
  double positive = 0, negative = 0, kept = 0;
  for (int k = 0; k < n; ++k) (values[k] > 0 ? positive : negative) += std::abs(values[k]);
  for (int c = 0; c < dims; ++c) kept += std::max(0.0, values[c]);
  e.captured = positive > 0 ? kept / positive : 0;
  e.negative = positive + negative > 0 ? negative / (positive + negative) : 0;
  return e;
}

KnnResult knn_classify(const Eigen::MatrixXd& d, const std::vector<std::string>& labels, int k, int folds) {
  const int n = static_cast<int>(d.rows());
  if (d.cols() != n || static_cast<int>(labels.size()) != n) invalid("k-NN: one label per shape is needed");
  if (k < 1) invalid("k-NN: k must be at least 1");
  if (folds == 1 || folds < 0 || folds > n) invalid("k-NN: folds must be 0 (leave-one-out) or in [2, n]");
  for (int i = 0; i < n; ++i)
    if (labels[i].empty()) invalid("k-NN: shape " + std::to_string(i) + " has no label");
  KnnResult out;
  out.k = k;
  out.folds = folds;
  out.total = n;
  out.predicted.resize(n);
  for (int i = 0; i < n; ++i) {
    std::vector<int> seen;
    for (int j = 0; j < n; ++j)
      if (j != i && (folds == 0 || j % folds != i % folds)) seen.push_back(j);
    if (seen.empty()) invalid("k-NN: shape " + std::to_string(i) + " has no neighbour to vote");
    // Nearest first; equal distances by index (a fixed answer).
    std::stable_sort(seen.begin(), seen.end(), [&](int a, int b) { return d(i, a) < d(i, b); });
    const int m = std::min<int>(k, static_cast<int>(seen.size()));
    std::map<std::string, std::pair<int, int>> votes;  // label -> (votes, rank of its nearest)
    for (int r = 0; r < m; ++r) {
      auto [it, fresh] = votes.try_emplace(labels[seen[r]], 0, r);
      ++it->second.first;
    }
    const std::string* best = nullptr;
    std::pair<int, int> top{-1, 0};
    for (const auto& [label, v] : votes)
      if (v.first > top.first || (v.first == top.first && v.second < top.second)) {
        top = v;
        best = &label;
      }
    out.predicted[i] = *best;
    out.correct += *best == labels[i];
  }
  out.accuracy = static_cast<double>(out.correct) / n;
  return out;
}

}  // namespace brenier::distance
